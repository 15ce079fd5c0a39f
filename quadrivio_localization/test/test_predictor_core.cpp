// gtest of the predictor's core (include/quadrivio_localization/predictor.h), without ROS:
// the exact bicycle-model arc, the readings held until the next one, the calibration, the
// steering limit, the distance driven on odometry alone, and bad readings refused.
#include <gtest/gtest.h>

#include <cmath>

#include <quadrivio_localization/predictor.h>

namespace ql = quadrivio_localization;

namespace
{
constexpr double kL = 1.25, kRatio = 1.0, kMaxDelta = 0.42;

ql::Predictor make()
{
  return ql::Predictor(kL, kRatio, kMaxDelta);
}
}  // namespace

TEST(PredictorCore, NoEstimateNoReadingsHoldsThePose)
{
  ql::Predictor p = make();
  EXPECT_FALSE(p.hasEstimate());
  p.setEstimate(10.0, ql::Pose2{ 1.0, 2.0, 0.3 });
  EXPECT_TRUE(p.hasEstimate());
  const ql::Pose2 q = p.predict(11.0);  // no readings: nothing moves it
  EXPECT_DOUBLE_EQ(q.x, 1.0);
  EXPECT_DOUBLE_EQ(q.y, 2.0);
  EXPECT_DOUBLE_EQ(q.theta, 0.3);
}

TEST(PredictorCore, StraightLineAtTheCalibratedSpeed)
{
  ql::Predictor p = make();
  ql::ModelCalibration c;
  c.speed_scale = 1.1;
  p.setCalibration(c);
  p.setEstimate(0.0, ql::Pose2{ 0.0, 0.0, M_PI / 2 });
  ASSERT_TRUE(p.addReading({ 0.0, 2.0, 0.0 }));
  double travelled = -1.0;
  const ql::Pose2 q = p.predict(1.5, &travelled);
  EXPECT_NEAR(q.x, 0.0, 1e-12);
  EXPECT_NEAR(q.y, 1.1 * 2.0 * 1.5, 1e-12);
  EXPECT_NEAR(q.theta, M_PI / 2, 1e-12);
  EXPECT_NEAR(travelled, 1.1 * 2.0 * 1.5, 1e-12);
}

TEST(PredictorCore, AnArcOfTheBicycleModelIsExact)
{
  ql::Predictor p = make();
  p.setEstimate(0.0, ql::Pose2{ 0.0, 0.0, 0.0 });
  const double h = 0.2, v = 1.5, T = 2.0;
  ASSERT_TRUE(p.addReading({ 0.0, v, h }));
  const ql::Pose2 q = p.predict(T);
  const double w = v * std::tan(kRatio * h) / kL, r = v / w;
  EXPECT_NEAR(q.theta, w * T, 1e-12);
  EXPECT_NEAR(q.x, r * std::sin(w * T), 1e-12);
  EXPECT_NEAR(q.y, r * (1.0 - std::cos(w * T)), 1e-12);
}

TEST(PredictorCore, EachReadingHoldsUntilTheNextAndTheSteeringLimitClamps)
{
  ql::Predictor p = make();
  p.setEstimate(0.0, ql::Pose2{ 0.0, 0.0, 0.0 });
  ASSERT_TRUE(p.addReading({ 0.0, 1.0, 0.0 }));
  ASSERT_TRUE(p.addReading({ 1.0, 1.0, 5.0 }));  // beyond the handlebar's limit: clamped to kMaxDelta
  double travelled = 0.0;
  const ql::Pose2 q = p.predict(2.0, &travelled);
  const ql::Pose2 first = p.step(ql::Pose2{ 0.0, 0.0, 0.0 }, 1.0, 0.0, 1.0);
  const ql::Pose2 want = p.step(first, 1.0, kMaxDelta, 1.0);
  EXPECT_NEAR(first.x, 1.0, 1e-12);
  EXPECT_NEAR(q.x, want.x, 1e-12);
  EXPECT_NEAR(q.y, want.y, 1e-12);
  EXPECT_NEAR(q.theta, 1.0 * std::tan(kMaxDelta) / kL, 1e-12);
  EXPECT_NEAR(travelled, 2.0, 1e-12);
}

TEST(PredictorCore, TheHandlebarOffsetAndGainAreApplied)
{
  ql::Predictor p = make();
  ql::ModelCalibration c;
  c.handlebar_offset = 0.05;
  c.steering_gain = 0.9;
  p.setCalibration(c);
  p.setEstimate(0.0, ql::Pose2{ 0.0, 0.0, 0.0 });
  ASSERT_TRUE(p.addReading({ 0.0, 1.0, 0.1 }));
  const ql::Pose2 q = p.predict(1.0);
  EXPECT_NEAR(q.theta, std::tan(0.9 * (0.1 + 0.05)) / kL, 1e-12);
  double v = 0.0, w = 0.0;
  ASSERT_TRUE(p.latest(v, w));
  EXPECT_DOUBLE_EQ(v, 1.0);
  EXPECT_NEAR(w, std::tan(0.9 * 0.15) / kL, 1e-12);
}

TEST(PredictorCore, ReversingTravelsADistanceToo)
{
  ql::Predictor p = make();
  p.setEstimate(0.0, ql::Pose2{ 0.0, 0.0, 0.0 });
  ASSERT_TRUE(p.addReading({ 0.0, -1.0, 0.0 }));
  double travelled = 0.0;
  const ql::Pose2 q = p.predict(0.5, &travelled);
  EXPECT_NEAR(q.x, -0.5, 1e-12);
  EXPECT_NEAR(travelled, 0.5, 1e-12);  // the stale-estimate budget counts both directions
}

TEST(PredictorCore, BadOrOutOfOrderReadingsAreRefused)
{
  ql::Predictor p = make();
  EXPECT_TRUE(p.addReading({ 1.0, 1.0, 0.0 }));
  EXPECT_FALSE(p.addReading({ 0.5, 1.0, 0.0 }));        // older than the last
  EXPECT_FALSE(p.addReading({ 2.0, NAN, 0.0 }));        // not finite
  EXPECT_FALSE(p.addReading({ 2.0, 1.0, INFINITY }));
  EXPECT_FALSE(p.addReading({ NAN, 1.0, 0.0 }));
  EXPECT_EQ(p.readings().size(), 1u);
}

TEST(PredictorCore, ATargetBeforeTheEstimateIsTheEstimate)
{
  ql::Predictor p = make();
  p.setEstimate(5.0, ql::Pose2{ 3.0, 4.0, 1.0 });
  ASSERT_TRUE(p.addReading({ 4.0, 2.0, 0.1 }));
  double travelled = -1.0;
  const ql::Pose2 q = p.predict(4.5, &travelled);
  EXPECT_DOUBLE_EQ(q.x, 3.0);
  EXPECT_DOUBLE_EQ(travelled, 0.0);
}

int main(int argc, char** argv)
{
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
