// The OMPL core's C interface (src/ompl_core.cpp), as ompl_planner.py calls it through
// ctypes: bad arguments refused without a crash, the footprint test on the cost grid, the
// curve lengths against hand values, a plan on an open yard and on a blocked one, and the
// messages a caller gets. Python's test_curves_mprim.py cross-tests the same functions
// against the Python curves; this runs without Python.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

extern "C" {
const char *qv_ompl_planners();
const char *qv_ompl_version();
void *qv_map_create(const uint8_t *cost, int width, int height, double resolution, double front, double rear,
                    double left, double right);
void qv_map_destroy(void *map);
int qv_map_pose_cost(void *map, double x, double y, double th);
double qv_weighted_rs_cost(double x0, double y0, double th0, double x1, double y1, double th1, double rho,
                           double reverse_cost);
double qv_dubins_length(double x0, double y0, double th0, double x1, double y1, double th1, double rho);
double qv_curve_length(double x0, double y0, double th0, double x1, double y1, double th1, double rho, int reverse);
int qv_ompl_plan(void *map_handle, double turning_radius, int reverse, const char *planner_name, double budget,
                 double first_budget, double simplify, double range, double check_resolution, int stop_at_first,
                 double reverse_cost, double cost_weight, unsigned int seed, const double *start, const double *goal,
                 double sample_step, const volatile int *cancel, int *out_n, double *stats, char *msg, int msg_len);
int qv_ompl_fetch(void *map_handle, double *out, int cap);
}

namespace
{
// The vehicle's footprint about the rear axle (vehicle.yaml's body, no padding) [m].
const double kFront = 1.665, kRear = 0.4, kSide = 0.59, kRho = 2.8;

// A yard of w x h cells at res, free (0), with an optional wall of lethal cells (255)
// across x = wall_x from y = 0 to wall_top.
struct Yard
{
    std::vector<uint8_t> cost;
    void *map = nullptr;
    Yard(int w, int h, double res, double wall_x = -1.0, double wall_top = 0.0) : cost((size_t)w * h, 0)
    {
        for (int r = 0; r < h; ++r)
            for (int c = 0; c < w; ++c)
                if (wall_x >= 0 && std::fabs((c + 0.5) * res - wall_x) < 0.5 && (r + 0.5) * res < wall_top)
                    cost[(size_t)r * w + c] = 255;
        map = qv_map_create(cost.data(), w, h, res, kFront, kRear, kSide, kSide);
    }
    ~Yard() { qv_map_destroy(map); }
};

struct Plan
{
    int rc = -1, n = 0;
    double stats[7];
    char msg[256] = {0};
};

Plan plan(void *map, const double *start, const double *goal, const char *planner = "RRTConnect", int reverse = 1,
          double budget = 1.0)
{
    Plan p;
    p.rc = qv_ompl_plan(map, kRho, reverse, planner, budget, budget, 0.2, 0.0, 0.0, 1, 2.0, 1.0, 7u, start, goal, 0.1,
                        nullptr, &p.n, p.stats, p.msg, sizeof(p.msg));
    return p;
}
}  // namespace

TEST(OmplCore, BadArgumentsAreRefusedNotCrashed)
{
    uint8_t cell = 0;
    EXPECT_EQ(qv_map_create(nullptr, 10, 10, 0.2, kFront, kRear, kSide, kSide), nullptr);
    EXPECT_EQ(qv_map_create(&cell, 0, 10, 0.2, kFront, kRear, kSide, kSide), nullptr);
    EXPECT_EQ(qv_map_create(&cell, 1, 1, 0.0, kFront, kRear, kSide, kSide), nullptr);
    EXPECT_EQ(qv_map_create(&cell, 1, 1, std::nan(""), kFront, kRear, kSide, kSide), nullptr);
    Yard yard(100, 100, 0.2);
    const double s[3] = {5, 10, 0}, g[3] = {15, 10, 0};
    Plan p;
    p.rc = qv_ompl_plan(nullptr, kRho, 1, "RRTConnect", 1.0, 1.0, 0.2, 0, 0, 1, 2.0, 1.0, 1u, s, g, 0.1, nullptr,
                        &p.n, p.stats, p.msg, sizeof(p.msg));
    EXPECT_EQ(p.rc, 2);
    EXPECT_STREQ(p.msg, "bad arguments");
    p.rc = qv_ompl_plan(yard.map, -1.0, 1, "RRTConnect", 1.0, 1.0, 0.2, 0, 0, 1, 2.0, 1.0, 1u, s, g, 0.1, nullptr,
                        &p.n, p.stats, p.msg, sizeof(p.msg));
    EXPECT_EQ(p.rc, 2);  // a negative turning radius
    Plan q = plan(yard.map, s, g, "NoSuchPlanner");
    EXPECT_EQ(q.rc, 2);
    EXPECT_NE(std::string(q.msg).find("unknown OMPL planner 'NoSuchPlanner'"), std::string::npos) << q.msg;
    EXPECT_NE(std::string(q.msg).find("RRTConnect"), std::string::npos);  // the message lists the known ones
}

TEST(OmplCore, ThePlannerListAndVersion)
{
    EXPECT_NE(std::string(qv_ompl_planners()).find("RRTConnect"), std::string::npos);
    EXPECT_NE(std::string(qv_ompl_planners()).find("BITstar"), std::string::npos);
    // "1.5.2": built from the numeric macros (Debian's OMPL_VERSION is an empty string)
    std::string v = qv_ompl_version();
    EXPECT_EQ(v.rfind("1.", 0), 0u) << v;
    EXPECT_EQ(std::count(v.begin(), v.end(), '.'), 2) << v;
}

TEST(OmplCore, TheFootprintOnTheCostGrid)
{
    Yard yard(100, 100, 0.2, 10.0, 20.0);  // a wall across x = 10 m, the whole height
    EXPECT_EQ(qv_map_pose_cost(yard.map, 5.0, 10.0, 0.0), 0);
    // the nose (1.665 m ahead) reaches the wall's cells (centres within 0.5 m of x = 10: 9.6-10.4 m) past x = 7.94 m
    EXPECT_EQ(qv_map_pose_cost(yard.map, 7.7, 10.0, 0.0), 0);
    EXPECT_EQ(qv_map_pose_cost(yard.map, 8.0, 10.0, 0.0), 255);
    // turned away from the wall, the tail (0.4 m) is what comes close
    EXPECT_EQ(qv_map_pose_cost(yard.map, 9.4, 10.0, M_PI), 255);  // the tail (to 9.8 m) on the wall's cells (9.6-10.4 m)
    EXPECT_EQ(qv_map_pose_cost(yard.map, 8.0, 10.0, M_PI), 0);
    // leaving the grid counts as an obstacle
    EXPECT_EQ(qv_map_pose_cost(yard.map, 0.3, 10.0, 0.0), 255);
    // a costly cell under the footprint gives its cost
    Yard costly(100, 100, 0.2);
    costly.cost[(size_t)50 * 100 + 30] = 77;  // the cell at (6.1, 10.1) m
    void *m = qv_map_create(costly.cost.data(), 100, 100, 0.2, kFront, kRear, kSide, kSide);
    EXPECT_EQ(qv_map_pose_cost(m, 5.5, 10.0, 0.0), 77);
    EXPECT_EQ(qv_map_pose_cost(m, 3.0, 10.0, 0.0), 0);
    qv_map_destroy(m);
}

TEST(OmplCore, CurveLengthsAgainstHandValues)
{
    // straight ahead: both curves are the segment
    EXPECT_NEAR(qv_curve_length(0, 0, 0, 5, 0, 0, kRho, 1), 5.0, 1e-9);
    EXPECT_NEAR(qv_curve_length(0, 0, 0, 5, 0, 0, kRho, 0), 5.0, 1e-9);
    EXPECT_NEAR(qv_dubins_length(0, 0, 0, 5, 0, 0, kRho), 5.0, 1e-9);
    // straight back: Reeds-Shepp reverses 5 m; Dubins must turn around (longer than a half circle)
    EXPECT_NEAR(qv_curve_length(0, 0, 0, -5, 0, 0, kRho, 1), 5.0, 1e-9);
    EXPECT_GT(qv_curve_length(0, 0, 0, -5, 0, 0, kRho, 0), 5.0 + M_PI * kRho);
    // a quarter circle to the left: rho pi / 2
    EXPECT_NEAR(qv_curve_length(0, 0, 0, kRho, kRho, M_PI / 2, kRho, 1), kRho * M_PI / 2, 1e-6);
    EXPECT_NEAR(qv_dubins_length(0, 0, 0, kRho, kRho, M_PI / 2, kRho), kRho * M_PI / 2, 1e-6);
    // reversing weighted: the same words, reverse parts counted twice
    EXPECT_NEAR(qv_weighted_rs_cost(0, 0, 0, -5, 0, 0, kRho, 2.0), 10.0, 1e-6);
    EXPECT_NEAR(qv_weighted_rs_cost(0, 0, 0, 5, 0, 0, kRho, 2.0), 5.0, 1e-6);
    EXPECT_NEAR(qv_weighted_rs_cost(1, 2, 0.3, 4, -1, 2.0, kRho, 1.0), qv_curve_length(1, 2, 0.3, 4, -1, 2.0, kRho, 1),
                1e-6);
    // Reeds-Shepp is symmetric: the way back reversed is the way there
    EXPECT_NEAR(qv_curve_length(1, 2, 0.3, 4, -1, 2.0, kRho, 1), qv_curve_length(4, -1, 2.0, 1, 2, 0.3, kRho, 1), 1e-6);
}

TEST(OmplCore, APlanOnAnOpenYardAndItsPoses)
{
    Yard yard(150, 100, 0.2);  // 30 m x 20 m
    const double s[3] = {4, 10, 0}, g[3] = {26, 12, 0.5};
    Plan p = plan(yard.map, s, g);
    ASSERT_EQ(p.rc, 0) << p.msg;
    ASSERT_GT(p.n, 2);
    std::vector<double> poses((size_t)p.n * 4);
    ASSERT_EQ(qv_ompl_fetch(yard.map, poses.data(), p.n), p.n);
    EXPECT_NEAR(poses[0], s[0], 1e-6);
    EXPECT_NEAR(poses[1], s[1], 1e-6);
    EXPECT_NEAR(poses[4 * (p.n - 1) + 0], g[0], 1e-9);  // ends exactly on the goal
    EXPECT_NEAR(poses[4 * (p.n - 1) + 1], g[1], 1e-9);
    EXPECT_NEAR(poses[4 * (p.n - 1) + 2], g[2], 1e-9);
    double length = 0;
    for (int i = 0; i < p.n; ++i)
    {
        EXPECT_LT(qv_map_pose_cost(yard.map, poses[4 * i], poses[4 * i + 1], poses[4 * i + 2]), 255);
        if (i > 0)
        {
            double step = std::hypot(poses[4 * i] - poses[4 * i - 4], poses[4 * i + 1] - poses[4 * i - 3]);
            EXPECT_LT(step, 0.1 + 1e-6);  // sampled at sample_step
            length += step;
        }
    }
    EXPECT_NEAR(p.stats[4], length, 0.05 * length);  // the reported length is the poses'
    EXPECT_GE(p.stats[4], std::hypot(g[0] - s[0], g[1] - s[1]));
    EXPECT_GE(p.stats[0], 0.0);  // time to the first solution
    // fetch copies at most cap poses
    double two[8];
    EXPECT_EQ(qv_ompl_fetch(yard.map, two, 2), 2);
    EXPECT_EQ(two[0], poses[0]);
}

TEST(OmplCore, BlockedStartsGoalsAndWallsAreSaid)
{
    Yard walled(150, 100, 0.2, 15.0, 20.0);  // a wall across the whole yard
    const double s[3] = {4, 10, 0}, g[3] = {26, 10, 0};
    Plan p = plan(walled.map, s, g, "RRTConnect", 1, 0.3);
    EXPECT_EQ(p.rc, 1);
    EXPECT_GT(std::strlen(p.msg), 0u);
    const double in_wall[3] = {14.5, 10, 0};
    Plan q = plan(walled.map, in_wall, g);
    EXPECT_EQ(q.rc, 1);
    EXPECT_STREQ(q.msg, "start in collision");
    Plan r = plan(walled.map, s, in_wall);
    EXPECT_EQ(r.rc, 1);
    EXPECT_STREQ(r.msg, "goal in collision");
    // a wall with a gap at the top: the plan goes through it, every pose clear
    Yard gap(150, 100, 0.2, 15.0, 12.0);
    Plan ok = plan(gap.map, s, g, "RRTConnect", 1, 2.0);
    ASSERT_EQ(ok.rc, 0) << ok.msg;
    std::vector<double> poses((size_t)ok.n * 4);
    qv_ompl_fetch(gap.map, poses.data(), ok.n);
    bool through = false;
    for (int i = 0; i < ok.n; ++i)
    {
        EXPECT_LT(qv_map_pose_cost(gap.map, poses[4 * i], poses[4 * i + 1], poses[4 * i + 2]), 255);
        through |= std::fabs(poses[4 * i] - 15.0) < 0.5 && poses[4 * i + 1] > 12.0;
    }
    EXPECT_TRUE(through);
}

int main(int argc, char **argv)
{
    testing::InitGoogleTest(&argc, argv);
    return RUN_ALL_TESTS();
}
