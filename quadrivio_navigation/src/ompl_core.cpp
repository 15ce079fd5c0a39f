// OMPL planning core of quadrivio_navigation, called from Python through ctypes
// (quadrivio_navigation/ompl_planner.py). Debian's libompl 1.5 has the Reeds-Shepp and
// Dubins state spaces that the pinned Python bindings lack (see the README), and C++
// collision checks keep a planner's thousands of validity calls off the interpreter.
//
// The map is a cost grid (uint8, 255 = lethal) in its own frame: metres from cell
// (0, 0)'s outer corner, x along the columns. A state (x, y, theta) is valid when the
// vehicle's footprint rectangle touches no lethal cell and stays on the grid, decided
// exactly by the separating-axis test of the Python planner's
// quadrivio_navigation.costmap.footprint_cells (about a microsecond a state). Motions are
// checked every `check_resolution` metres of Reeds-Shepp (Dubins) curve.
//
// The objective is the lattice planner's: the curve's length with reverse parts counted
// `reverse_cost` times, times 1 + cost_weight * (highest cell cost along the curve) / 254.
//
// Determinism: OMPL seeds every RNG it creates from one global seed generator; it is
// reseeded with the request's seed before each plan (OMPL logs an error when this
// happens after the first RNG was made, which is why messages are silenced around it),
// and plans are serialised by a mutex. With a planner that stops at its first
// solution and step-bounded simplification the same request gives the same path.

#include "quadrivio_navigation/curves_core.h"

#include <ompl/base/OptimizationObjective.h>
#include <ompl/base/ProblemDefinition.h>
#include <ompl/base/SpaceInformation.h>
#include <ompl/base/objectives/PathLengthOptimizationObjective.h>
#include <ompl/base/spaces/DubinsStateSpace.h>
#include <ompl/base/spaces/ReedsSheppStateSpace.h>
#include <ompl/geometric/PathGeometric.h>
#include <ompl/geometric/PathSimplifier.h>
#include <ompl/geometric/planners/fmt/FMT.h>
#include <ompl/geometric/planners/informedtrees/ABITstar.h>
#include <ompl/geometric/planners/informedtrees/BITstar.h>
#include <ompl/geometric/planners/kpiece/BKPIECE1.h>
#include <ompl/geometric/planners/kpiece/KPIECE1.h>
#include <ompl/geometric/planners/prm/LazyPRMstar.h>
#include <ompl/geometric/planners/prm/PRMstar.h>
#include <ompl/geometric/planners/rrt/InformedRRTstar.h>
#include <ompl/geometric/planners/rrt/RRT.h>
#include <ompl/geometric/planners/rrt/RRTConnect.h>
#include <ompl/geometric/planners/rrt/RRTstar.h>
#include <ompl/geometric/planners/sst/SST.h>
#include <ompl/util/Console.h>
#include <ompl/util/RandomNumbers.h>
#include <ompl/config.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <mutex>
#include <string>
#include <vector>

namespace ob = ompl::base;
namespace og = ompl::geometric;

namespace
{
using namespace qv_curves;
const uint8_t kLethal = 255;
std::mutex g_plan_mutex;

const char *kPlanners = "RRTConnect,RRT,RRTstar,InformedRRTstar,BITstar,ABITstar,PRMstar,LazyPRMstar,KPIECE1,BKPIECE1,"
                        "SST,FMT";

struct Footprint
{
    double front, rear, left, right;
};

struct Map
{
    std::vector<uint8_t> cost;
    int width, height;
    double res;
    Footprint fp;
    std::vector<double> last;  // the last plan's poses (x, y, theta, direction)

    // Highest cell cost under the footprint at (x, y, th); kLethal when it touches an
    // obstacle or leaves the grid. The same separating-axis test as footprintCells, with
    // an early exit.
    uint8_t worst(double x, double y, double th) const
    {
        double c = std::cos(th), s = std::sin(th);
        double lx[4] = {fp.front, fp.front, -fp.rear, -fp.rear};
        double ly[4] = {-fp.right, fp.left, fp.left, -fp.right};
        double minx = 1e300, maxx = -1e300, miny = 1e300, maxy = -1e300;
        for (int i = 0; i < 4; ++i)
        {
            double px = x + c * lx[i] - s * ly[i], py = y + s * lx[i] + c * ly[i];
            minx = std::min(minx, px);
            maxx = std::max(maxx, px);
            miny = std::min(miny, py);
            maxy = std::max(maxy, py);
        }
        int c0 = (int)std::floor(minx / res), c1 = (int)std::floor(maxx / res);
        int r0 = (int)std::floor(miny / res), r1 = (int)std::floor(maxy / res);
        double half = 0.5 * res * (std::fabs(c) + std::fabs(s));
        double mu = 0.5 * (fp.front - fp.rear), hu = 0.5 * (fp.front + fp.rear) + half - 1e-9;
        double mv = 0.5 * (fp.left - fp.right), hv = 0.5 * (fp.left + fp.right) + half - 1e-9;
        uint8_t w = 0;
        for (int r = r0; r <= r1; ++r)
        {
            double dy = (r + 0.5) * res - y;
            for (int cc = c0; cc <= c1; ++cc)
            {
                double dx = (cc + 0.5) * res - x;
                if (std::fabs(c * dx + s * dy - mu) >= hu || std::fabs(-s * dx + c * dy - mv) >= hv)
                    continue;
                if (r < 0 || cc < 0 || r >= height || cc >= width)
                    return kLethal;
                uint8_t v = cost[(size_t)r * width + cc];
                if (v > w)
                {
                    if (v == kLethal)
                        return kLethal;
                    w = v;
                }
            }
        }
        return w;
    }
};


// SE(2) whose motions are curves of words (segments 'L', 'S', 'R' of signed length in
// radii): distance is the word's cost (reverse parts counted reverse_cost times),
// interpolation follows the word. The subclasses say which word joins two states.
class WordSpace : public ob::SE2StateSpace
{
public:
    WordSpace(double rho, double reverseCost, bool symmetric) : rho_(rho), rc_(reverseCost), symmetric_(symmetric)
    {
    }

    virtual rs::Word word(const ob::State *a, const ob::State *b) const = 0;

    double distance(const ob::State *a, const ob::State *b) const override
    {
        return rho_ * word(a, b).cost;
    }

    bool isMetricSpace() const override
    {
        return symmetric_;
    }

    bool hasSymmetricDistance() const override
    {
        return symmetric_;
    }

    bool hasSymmetricInterpolate() const override
    {
        return symmetric_;
    }

    void interpolate(const ob::State *from, const ob::State *to, double t, ob::State *state) const override
    {
        if (t >= 1.0)
        {
            copyState(state, to);
            return;
        }
        rs::Word w = word(from, to);
        // t is a fraction of the curve's cost: walk the segments to that cost
        double target = t * w.cost, acc = 0.0;
        auto *s0 = from->as<StateType>();
        double x = s0->getX(), y = s0->getY(), th = s0->getYaw();
        for (int i = 0; i < w.n && target > acc; ++i)
        {
            double weight = w.len[i] >= 0 ? 1.0 : rc_;
            double segCost = std::fabs(w.len[i]) * weight;
            double part = std::min(segCost, target - acc) / weight;  // |length| driven, in radii
            advance(x, y, th, w.kind[i], (w.len[i] >= 0 ? part : -part) * rho_, rho_);
            acc += segCost;
        }
        auto *out = state->as<StateType>();
        out->setXY(x, y);
        out->setYaw(wrap(th));
    }

    void sanityChecks() const override
    {
        double zero = std::numeric_limits<double>::epsilon();
        double eps = .1;
        int flags = ~(ob::StateSpace::STATESPACE_INTERPOLATION | ob::StateSpace::STATESPACE_TRIANGLE_INEQUALITY |
                      ob::StateSpace::STATESPACE_DISTANCE_BOUND);
        if (!symmetric_)
            flags &= ~ob::StateSpace::STATESPACE_DISTANCE_SYMMETRIC;
        ob::StateSpace::sanityChecks(zero, eps, flags);
    }

protected:
    double rho_, rc_;
    bool symmetric_;
};

// Weighted Reeds-Shepp curves. Not symmetric once reverse_cost > 1: the same curve driven
// the other way swaps forward and reverse. OMPL checks and assembles motions in path
// order, so that is sound.
class WeightedReedsSheppStateSpace : public WordSpace
{
public:
    WeightedReedsSheppStateSpace(double rho, double reverseCost) : WordSpace(rho, reverseCost, reverseCost == 1.0)
    {
        setName("WeightedReedsShepp" + getName());
    }

    rs::Word word(const ob::State *a, const ob::State *b) const override
    {
        auto *s1 = a->as<StateType>();
        auto *s2 = b->as<StateType>();
        double dx = s2->getX() - s1->getX(), dy = s2->getY() - s1->getY();
        double c = std::cos(s1->getYaw()), s = std::sin(s1->getYaw());
        return rs::cheapest((c * dx + s * dy) / rho_, (-s * dx + c * dy) / rho_, s2->getYaw() - s1->getYaw(), rc_);
    }
};

// Dubins curves (forwards only), on our own word computation (see namespace dubins). Not
// symmetric: the curve from b to a is another one.
class DubinsSpace : public WordSpace
{
public:
    explicit DubinsSpace(double rho) : WordSpace(rho, 1.0, false)
    {
        setName("QvDubins" + getName());
    }

    rs::Word word(const ob::State *a, const ob::State *b) const override
    {
        auto *s1 = a->as<StateType>();
        auto *s2 = b->as<StateType>();
        return dubins::shortest((s2->getX() - s1->getX()) / rho_, (s2->getY() - s1->getY()) / rho_, s1->getYaw(),
                                s2->getYaw());
    }
};

// One curve between two states as segments (kind 'L', 'S', 'R'; signed length in m).
struct Segments
{
    char kind[5];
    double len[5];
    int n = 0;
};

Segments curveSegments(const ob::StateSpacePtr &space, double rho, const ob::State *a,
                       const ob::State *b)
{
    Segments out;
    rs::Word w = space->as<WordSpace>()->word(a, b);
    for (int i = 0; i < w.n; ++i)
    {
        if (std::fabs(w.len[i]) < 1e-12)
            continue;
        out.kind[out.n] = w.kind[i];
        out.len[out.n++] = w.len[i] * rho;
    }
    return out;
}

// Checks a motion along its curve every `step` metres, computing the curve once (OMPL's
// DiscreteMotionValidator asks the space to interpolate afresh for every check).
class CurveMotionValidator : public ob::MotionValidator
{
public:
    CurveMotionValidator(const ob::SpaceInformationPtr &si, bool reverse, double rho, double step)
      : ob::MotionValidator(si), reverse_(reverse), rho_(rho), step_(step)
    {
    }

    bool checkMotion(const ob::State *s1, const ob::State *s2) const override
    {
        std::pair<ob::State *, double> unused(nullptr, 0.0);
        return walk(s1, s2, nullptr);
    }

    bool checkMotion(const ob::State *s1, const ob::State *s2, std::pair<ob::State *, double> &lastValid) const override
    {
        return walk(s1, s2, &lastValid);
    }

private:
    bool walk(const ob::State *s1, const ob::State *s2, std::pair<ob::State *, double> *lastValid) const
    {
        if (!si_->isValid(s2))
        {
            invalid_++;
            if (lastValid)
                fill(s1, s2, 0.0, *lastValid);
            return false;
        }
        Segments seg = curveSegments(si_->getStateSpace(), rho_, s1, s2);
        double total = 0.0;
        for (int i = 0; i < seg.n; ++i)
            total += std::fabs(seg.len[i]);
        auto *a = s1->as<ob::SE2StateSpace::StateType>();
        double x = a->getX(), y = a->getY(), th = a->getYaw(), done = 0.0;
        ob::State *probe = si_->allocState();
        auto *p = probe->as<ob::SE2StateSpace::StateType>();
        bool ok = true;
        double lastGood = 0.0;
        for (int i = 0; i < seg.n && ok; ++i)
        {
            int n = std::max(1, (int)std::ceil(std::fabs(seg.len[i]) / step_));
            double x0 = x, y0 = y, th0 = th;
            for (int j = 1; j <= n; ++j)
            {
                double xx = x0, yy = y0, tt = th0;
                advance(xx, yy, tt, seg.kind[i], seg.len[i] * j / n, rho_);
                p->setXY(xx, yy);
                p->setYaw(wrap(tt));
                if (!si_->isValid(probe))
                {
                    ok = false;
                    break;
                }
                lastGood = done + std::fabs(seg.len[i]) * j / n;
                x = xx;
                y = yy;
                th = tt;
            }
            done += std::fabs(seg.len[i]);
        }
        si_->freeState(probe);
        if (ok)
            valid_++;
        else
        {
            invalid_++;
            if (lastValid)
                fill(s1, s2, total > 0 ? lastGood / total : 0.0, *lastValid);
        }
        return ok;
    }

    void fill(const ob::State *s1, const ob::State *s2, double t, std::pair<ob::State *, double> &lastValid) const
    {
        lastValid.second = t;
        if (lastValid.first)
            si_->getStateSpace()->interpolate(s1, s2, t, lastValid.first);
    }

    bool reverse_;
    double rho_, step_;
};

class CurveCostObjective : public ob::OptimizationObjective
{
public:
    CurveCostObjective(const ob::SpaceInformationPtr &si, const Map *map, bool reverse, double rho,
                       double reverseCost, double costWeight, double step)
      : ob::OptimizationObjective(si)
      , map_(map)
      , reverse_(reverse)
      , rho_(rho)
      , reverseCost_(reverseCost)
      , costWeight_(costWeight)
      , step_(step)
    {
        description_ = "curve length (reverse weighted) x cell cost";
        setCostThreshold(ob::Cost(0.0));
    }

    ob::Cost stateCost(const ob::State *) const override
    {
        return identityCost();
    }

    // The lattice's cost model: the curve's length (reverse parts weighted) times
    // 1 + cost_weight x the highest cell cost the footprint touches along the curve.
    ob::Cost motionCost(const ob::State *a, const ob::State *b) const override
    {
        double c = si_->distance(a, b);
        if (costWeight_ <= 0.0)
            return ob::Cost(c);
        Segments seg = curveSegments(si_->getStateSpace(), rho_, a, b);
        auto *sa = a->as<ob::SE2StateSpace::StateType>();
        double x = sa->getX(), y = sa->getY(), th = sa->getYaw();
        int w = map_->worst(x, y, th);
        for (int i = 0; i < seg.n; ++i)
        {
            int n = std::max(1, (int)std::ceil(std::fabs(seg.len[i]) / step_));
            double x0 = x, y0 = y, th0 = th;
            for (int j = 1; j <= n; ++j)
            {
                x = x0;
                y = y0;
                th = th0;
                advance(x, y, th, seg.kind[i], seg.len[i] * j / n, rho_);
                w = std::max(w, (int)map_->worst(x, y, th));
            }
        }
        if (w >= kLethal)
            w = 254;
        return ob::Cost(c * (1.0 + costWeight_ * w / 254.0));
    }

    ob::Cost motionCostHeuristic(const ob::State *a, const ob::State *b) const override
    {
        return ob::Cost(si_->distance(a, b));  // the curve's length, never more than its cost
    }

private:
    const Map *map_;
    bool reverse_;
    double rho_, reverseCost_, costWeight_, step_;
};

template <class P>
ob::PlannerPtr withRange(const ob::SpaceInformationPtr &si, double range)
{
    auto p = std::make_shared<P>(si);
    if (range > 0)
        p->setRange(range);
    return p;
}

ob::PlannerPtr makePlanner(const std::string &name, const ob::SpaceInformationPtr &si, double range)
{
    if (name == "RRTConnect")
        return withRange<og::RRTConnect>(si, range);
    if (name == "RRT")
        return withRange<og::RRT>(si, range);
    if (name == "RRTstar")
        return withRange<og::RRTstar>(si, range);
    if (name == "InformedRRTstar")
        return withRange<og::InformedRRTstar>(si, range);
    if (name == "KPIECE1")
        return withRange<og::KPIECE1>(si, range);
    if (name == "BKPIECE1")
        return withRange<og::BKPIECE1>(si, range);
    if (name == "SST")
        return withRange<og::SST>(si, range);
    if (name == "BITstar")
        return std::make_shared<og::BITstar>(si);
    if (name == "ABITstar")
        return std::make_shared<og::ABITstar>(si);
    if (name == "PRMstar")
        return std::make_shared<og::PRMstar>(si);
    if (name == "LazyPRMstar")
        return std::make_shared<og::LazyPRMstar>(si);
    if (name == "FMT")
        return std::make_shared<og::FMT>(si);
    return nullptr;
}

void setMessage(char *msg, int len, const std::string &text)
{
    if (msg && len > 0)
    {
        std::strncpy(msg, text.c_str(), (size_t)len - 1);
        msg[len - 1] = '\0';
    }
}

}  // namespace

extern "C" {

const char *qv_ompl_planners()
{
    return kPlanners;
}

// Built from the numeric macros: Debian's ompl/config.h defines OMPL_VERSION as "".
#define QV_STR2(x) #x
#define QV_STR(x) QV_STR2(x)
const char *qv_ompl_version()
{
    return QV_STR(OMPL_MAJOR_VERSION) "." QV_STR(OMPL_MINOR_VERSION) "." QV_STR(OMPL_PATCH_VERSION);
}

// A cost grid (row-major, row 0 at y = 0) and a footprint (m from base_link, padding
// included). Returns a handle for qv_ompl_plan, or null on bad arguments.
// OMPL's informational messages are turned off; warnings and errors still print.
void *qv_map_create(const uint8_t *cost, int width, int height, double resolution, double front, double rear,
                    double left, double right)
{
    if (!cost || width < 1 || height < 1 || !(resolution > 0))
        return nullptr;
    ompl::msg::setLogLevel(ompl::msg::LOG_WARN);
    auto *m = new Map();
    m->cost.assign(cost, cost + (size_t)width * height);
    m->width = width;
    m->height = height;
    m->res = resolution;
    m->fp = {front, rear, left, right};
    return m;
}

void qv_map_destroy(void *map)
{
    delete static_cast<Map *>(map);
}

// Highest cell cost under the footprint at a grid-frame pose; 255 when blocked.
int qv_map_pose_cost(void *map, double x, double y, double th)
{
    return static_cast<Map *>(map)->worst(x, y, th);
}

// The distance of `space` between two poses (the cross-checks below).
static double spaceDistance(const ob::StateSpacePtr &space, double x0, double y0, double th0, double x1, double y1,
                            double th1)
{
    ob::ScopedState<ob::SE2StateSpace> a(space), b(space);
    a->setXY(x0, y0);
    a->setYaw(th0);
    b->setXY(x1, y1);
    b->setYaw(th1);
    return space->distance(a.get(), b.get());
}

// Cost of the cheapest Reeds-Shepp word with reverse parts weighted, for cross-checks.
double qv_weighted_rs_cost(double x0, double y0, double th0, double x1, double y1, double th1, double rho,
                           double reverse_cost)
{
    return spaceDistance(std::make_shared<WeightedReedsSheppStateSpace>(rho, reverse_cost), x0, y0, th0, x1, y1, th1);
}

// Length of the Dubins curve the planner uses (DubinsSpace), for cross-checks.
double qv_dubins_length(double x0, double y0, double th0, double x1, double y1, double th1, double rho)
{
    return spaceDistance(std::make_shared<DubinsSpace>(rho), x0, y0, th0, x1, y1, th1);
}

// OMPL's Reeds-Shepp (reverse != 0) or Dubins distance between two poses, for cross-checks.
double qv_curve_length(double x0, double y0, double th0, double x1, double y1, double th1, double rho, int reverse)
{
    ob::StateSpacePtr space = reverse ? ob::StateSpacePtr(new ob::ReedsSheppStateSpace(rho)) :
                                        ob::StateSpacePtr(new ob::DubinsStateSpace(rho));
    return spaceDistance(space, x0, y0, th0, x1, y1, th1);
}

// Plan from start to goal (x, y, theta in the grid frame). The path's poses (x, y,
// theta, direction of the motion to the next pose) are kept with the map: their number
// goes to out_n, qv_ompl_fetch copies them. stats get [time to first solution s, solve
// time s, simplification time s, cost, length m, states in the planner's data, first
// solution's cost]. Without a path by first_budget s the search stops (the caller may hand
// over to another planner); with one, restarts improve it until budget s. Returns 0 on
// success, 1 when no path was found (msg says why), 2 on bad arguments.
static int plan(void *map_handle, double turning_radius, int reverse, const char *planner_name, double budget,
                double first_budget, double simplify, double range, double check_resolution, int stop_at_first,
                double reverse_cost, double cost_weight, unsigned int seed, const double *start, const double *goal,
                double sample_step, const volatile int *cancel, int *out_n, double *stats, char *msg, int msg_len)
{
    auto *map = static_cast<Map *>(map_handle);
    if (!map || !planner_name || !start || !goal || !out_n || !stats || !(turning_radius > 0) ||
        !(budget > 0) || !(sample_step > 0))
    {
        setMessage(msg, msg_len, "bad arguments");
        return 2;
    }
    for (int i = 0; i < 7; ++i)
        stats[i] = std::numeric_limits<double>::quiet_NaN();
    const double rho = turning_radius;
    ob::StateSpacePtr space = reverse ? ob::StateSpacePtr(new WeightedReedsSheppStateSpace(rho, reverse_cost)) :
                                        ob::StateSpacePtr(new DubinsSpace(rho));
    ob::RealVectorBounds bounds(2);
    bounds.setLow(0, 0.0);
    bounds.setHigh(0, map->width * map->res);
    bounds.setLow(1, 0.0);
    bounds.setHigh(1, map->height * map->res);
    space->as<ob::SE2StateSpace>()->setBounds(bounds);

    // seed before anything makes an RNG (see the file's header)
    ompl::msg::LogLevel level = ompl::msg::getLogLevel();
    ompl::msg::setLogLevel(ompl::msg::LOG_NONE);
    ompl::RNG::setSeed(seed == 0 ? 1u : seed);
    ompl::msg::setLogLevel(level);

    auto si = std::make_shared<ob::SpaceInformation>(space);
    si->setStateValidityChecker([map](const ob::State *s) {
        auto *st = s->as<ob::SE2StateSpace::StateType>();
        return map->worst(st->getX(), st->getY(), st->getYaw()) != kLethal;
    });
    double step = check_resolution > 0 ? check_resolution : 0.5 * map->res;
    si->setStateValidityCheckingResolution(std::min(1.0, step / space->getMaximumExtent()));
    si->setMotionValidator(std::make_shared<CurveMotionValidator>(si, reverse != 0, rho, step));
    si->setup();

    ob::ScopedState<ob::SE2StateSpace> s(space), g(space);
    s->setXY(start[0], start[1]);
    s->setYaw(wrap(start[2]));
    g->setXY(goal[0], goal[1]);
    g->setYaw(wrap(goal[2]));
    if (!si->isValid(s.get()))
    {
        setMessage(msg, msg_len, "start in collision");
        return 1;
    }
    if (!si->isValid(g.get()))
    {
        setMessage(msg, msg_len, "goal in collision");
        return 1;
    }
    auto pdef = std::make_shared<ob::ProblemDefinition>(si);
    pdef->setStartAndGoalStates(s, g, 1e-3);
    auto obj = std::make_shared<CurveCostObjective>(si, map, reverse != 0, rho, reverse ? reverse_cost : 1.0,
                                                    cost_weight, std::max(step, 0.5 * map->res));
    if (stop_at_first)
        obj->setCostThreshold(ob::Cost(std::numeric_limits<double>::infinity()));
    pdef->setOptimizationObjective(obj);

    auto t0 = std::chrono::steady_clock::now();
    auto elapsed = [&t0]() {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    };
    std::atomic<double> first{-1.0};
    double first_cost = std::numeric_limits<double>::quiet_NaN();
    pdef->setIntermediateSolutionCallback(
        [&](const ob::Planner *, const std::vector<const ob::State *> &, const ob::Cost c) {
            if (first.load() < 0)
            {
                first = elapsed();
                first_cost = c.value();
            }
        });
    ob::PlannerPtr planner = makePlanner(planner_name, si, range);
    if (!planner)
    {
        setMessage(msg, msg_len, std::string("unknown OMPL planner '") + planner_name + "' (" + kPlanners + ")");
        return 2;
    }
    planner->setProblemDefinition(pdef);
    planner->setup();
    // no solution (first < 0: optimising planners report theirs as they find them) by first_by: stop
    const double first_by = std::min(first_budget > 0 ? first_budget : budget, budget);
    ob::PlannerTerminationCondition ptc(
        [&]() { return (cancel && *cancel) || elapsed() > budget || (first.load() < 0 && elapsed() > first_by); });
    // Non-optimising planners (RRTConnect, KPIECE, ...) restart after each solution until
    // the budget ends, each path simplified, the cheapest kept: an anytime planner out of
    // a fast one. Optimising planners (RRT*, BIT*, ...) improve their own solution instead.
    const bool restart = !planner->getSpecs().optimizingPaths && !stop_at_first;
    og::PathSimplifier simplifier(si, pdef->getGoal(), obj);
    std::shared_ptr<og::PathGeometric> best;
    double best_cost = std::numeric_limits<double>::infinity();
    double simplify_time = 0.0, solve_time = 0.0;
    int rounds = 0;
    ob::PlannerStatus status;
    do
    {
        if (rounds > 0)
        {
            planner->clear();
            pdef->clearSolutionPaths();
        }
        double t_solve = elapsed();
        status = planner->solve(ptc);
        solve_time += elapsed() - t_solve;
        if (rounds == 0)
        {
            ob::PlannerData data(si);
            planner->getPlannerData(data);
            stats[5] = data.numVertices();
        }
        if (status != ob::PlannerStatus::EXACT_SOLUTION || !pdef->hasExactSolution())
            break;
        if (first.load() < 0)  // planners that do not report intermediate solutions
            first = elapsed();
        auto found = std::static_pointer_cast<og::PathGeometric>(pdef->getSolutionPath());
        auto p = std::make_shared<og::PathGeometric>(*found);
        if (std::isnan(first_cost))
            first_cost = p->cost(obj).value();
        double ts = elapsed();
        if (simplify > 0)
        {
            // step-bounded passes until nothing improves (deterministic); the time only as a stop
            for (int pass = 0; pass < 20 && elapsed() - ts < simplify && !(cancel && *cancel); ++pass)
            {
                bool a = simplifier.reduceVertices(*p);
                bool b = simplifier.shortcutPath(*p);
                bool c = simplifier.collapseCloseVertices(*p);
                if (!a && !b && !c)
                    break;
            }
            if (!p->check())  // cannot happen: each step is checked; keep the unsimplified path if it does
                p = std::make_shared<og::PathGeometric>(*found);
        }
        simplify_time += elapsed() - ts;
        double c = p->cost(obj).value();
        if (c < best_cost)
        {
            best_cost = c;
            best = p;
        }
        ++rounds;
    } while (restart && !ptc());
    if (!best)
    {
        std::string why = (cancel && *cancel) ? "cancelled" :
                          (status == ob::PlannerStatus::APPROXIMATE_SOLUTION || status == ob::PlannerStatus::TIMEOUT) ?
                                                "no path found within the time budget" :
                                                std::string("no path found (") + status.asString() + ")";
        setMessage(msg, msg_len, why);
        stats[1] = solve_time;
        return 1;
    }
    og::PathGeometric &p = *best;

    // sample the curves between consecutive states
    std::vector<double> poses;
    double length = 0.0;
    auto push = [&poses](double x, double y, double th, double dir) {
        poses.push_back(x);
        poses.push_back(y);
        poses.push_back(wrap(th));
        poses.push_back(dir);
    };
    const auto &states = p.getStates();
    {
        auto *st = states[0]->as<ob::SE2StateSpace::StateType>();
        push(st->getX(), st->getY(), st->getYaw(), 1.0);
    }
    for (size_t k = 0; k + 1 < states.size(); ++k)
    {
        auto *a = states[k]->as<ob::SE2StateSpace::StateType>();
        Segments seg = curveSegments(space, rho, states[k], states[k + 1]);
        double x = a->getX(), y = a->getY(), th = a->getYaw();
        for (int i = 0; i < seg.n; ++i)
        {
            double L = seg.len[i];
            double dir = L >= 0 ? 1.0 : -1.0;
            length += std::fabs(L);
            poses[poses.size() - 1] = dir;  // the motion from the previous pose
            int n = std::max(1, (int)std::ceil(std::fabs(L) / sample_step));
            double x0 = x, y0 = y, th0 = th;
            for (int j = 1; j <= n; ++j)
            {
                double xx = x0, yy = y0, tt = th0;
                advance(xx, yy, tt, seg.kind[i], L * j / n, rho);
                push(xx, yy, tt, dir);
                x = xx;
                y = yy;
                th = tt;
            }
        }
    }
    // the end exactly on the goal
    size_t np = poses.size() / 4;
    poses[4 * (np - 1) + 0] = goal[0];
    poses[4 * (np - 1) + 1] = goal[1];
    poses[4 * (np - 1) + 2] = wrap(goal[2]);
    stats[0] = first.load();
    stats[1] = solve_time;
    stats[2] = simplify_time;
    stats[3] = best_cost;
    stats[4] = length;
    stats[6] = first_cost;
    *out_n = (int)np;
    map->last.swap(poses);
    return 0;
}

int qv_ompl_plan(void *map_handle, double turning_radius, int reverse, const char *planner_name, double budget,
                 double first_budget, double simplify, double range, double check_resolution, int stop_at_first,
                 double reverse_cost, double cost_weight, unsigned int seed, const double *start, const double *goal,
                 double sample_step, const volatile int *cancel, int *out_n, double *stats, char *msg, int msg_len)
{
    std::lock_guard<std::mutex> lock(g_plan_mutex);
    // No C++ exception may cross into the Python caller: it would end the process.
    try
    {
        return plan(map_handle, turning_radius, reverse, planner_name, budget, first_budget, simplify, range,
                    check_resolution, stop_at_first, reverse_cost, cost_weight, seed, start, goal, sample_step, cancel,
                    out_n, stats, msg, msg_len);
    }
    catch (const std::exception &e)
    {
        setMessage(msg, msg_len, std::string("OMPL failed: ") + e.what());
        return 2;
    }
}

// Copy the last plan's poses (4 doubles each) into out, at most cap poses; returns how many.
int qv_ompl_fetch(void *map_handle, double *out, int cap)
{
    std::lock_guard<std::mutex> lock(g_plan_mutex);
    auto *map = static_cast<Map *>(map_handle);
    int n = std::min(cap, (int)(map->last.size() / 4));
    std::copy(map->last.begin(), map->last.begin() + 4 * n, out);
    return n;
}

}  // extern "C"
