// predictor: the localization's estimate carried forward to "now" at 50 Hz.
//
// Parameters (private): ~rate (Hz, 50), ~horizon (s, 0: predict to now; more: beyond
// now, to cover the control loop's own delay), ~max_dead_reckoning (m, 0.5) and
// ~estimate_age_floor (s, 0.15): stop predicting once the estimate is older than the floor
// and the vehicle has driven more than ~max_dead_reckoning on odometry alone since it (a
// dead or stalled localization: the distance driven on a stale estimate is a safety budget,
// so the age allowed falls with the speed; the floor is the estimate's normal age, 20 Hz
// keyframes and their delivery), ~max_age (s, 1.0: and whatever the speed, from an estimate
// older than this), ~max_future (s, 0.5: inputs stamped further ahead of the
// clock are dropped, and so is an estimate newer than that: after the clock moved back),
// ~map_frame (map), ~base_frame (base_link), ~realtime_priority (0: on the wall clock the 50 Hz beat
// runs on a thread of its own; above 0 at that SCHED_FIFO priority, when the system allows it; in sim time it is a
// callback of /clock, see onClockTick). When ROS time moves back (the simulator's
// ~reset, a bag loop) the predictor forgets its estimate, readings and calibration.
// Vehicle geometry: /vehicle/wheelbase, /vehicle/steering/ratio.
// Subscribes: localization/odom (nav_msgs/Odometry), vehicle/state
// (quadrivio_plc/VehicleState), localization/calibration (quadrivio_localization/Calibration).
// Publishes: localization/predicted (nav_msgs/Odometry), stamped with the predicted time.
#include <ros/ros.h>
#include <nav_msgs/Odometry.h>
#include <quadrivio_localization/Calibration.h>
#include <quadrivio_runtime/lockstep.h>
#include <quadrivio_localization/predictor.h>
#include <quadrivio_plc/VehicleState.h>
#include <rosgraph_msgs/Clock.h>

#include <pthread.h>
#include <sched.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <mutex>
#include <thread>

namespace ql = quadrivio_localization;

class PredictorNode
{
public:
  PredictorNode() : nh_(), pnh_("~"), lockstep_(nh_)
  {
    // The vehicle file's value, or the scenario's vehicle: override of it (as vehicle_params() in Python)
    auto vehicle = [this](const std::string& key, double& value) {
      return nh_.getParam("/scenario/vehicle/" + key, value) || nh_.getParam("/vehicle/" + key, value);
    };
    double wheelbase = 0.0, ratio = 1.0;
    if (!vehicle("wheelbase", wheelbase) || !(wheelbase > 0.0))
    {
      ROS_FATAL("predictor: /vehicle/wheelbase is missing or not positive (load vehicle.yaml into /vehicle)");
      ros::shutdown();
      return;
    }
    if (!vehicle("steering/ratio", ratio))
      ratio = 1.0;
    double max_angle = 0.0;
    if (!vehicle("steering/max_angle", max_angle) || !(max_angle > 0.0))
    {
      ROS_FATAL("predictor: /vehicle/steering/max_angle is missing or not positive (load vehicle.yaml into /vehicle)");
      ros::shutdown();
      return;
    }
    pnh_.param("rate", rate_, 50.0);
    pnh_.param("horizon", horizon_, 0.0);
    pnh_.param("max_age", max_age_, 1.0);
    pnh_.param("max_dead_reckoning", max_dead_reckoning_, 0.5);
    pnh_.param("estimate_age_floor", estimate_age_floor_, 0.15);
    pnh_.param("max_future", max_future_, 0.5);
    pnh_.param<std::string>("map_frame", map_frame_, "map");
    pnh_.param<std::string>("base_frame", base_frame_, "base_link");
    pnh_.param("realtime_priority", realtime_priority_, 0);
    if (!(rate_ > 0.0 && rate_ <= 1000.0) || !(horizon_ >= 0.0 && horizon_ <= 2.0) || !(max_age_ > 0.0) ||
        !(max_future_ >= 0.0 && max_future_ <= 60.0) || realtime_priority_ < 0 || realtime_priority_ > 99 ||
        !(max_dead_reckoning_ > 0.0) || !(estimate_age_floor_ >= 0.0 && estimate_age_floor_ <= max_age_))
    {
      ROS_FATAL("predictor: bad parameter: ~rate = %g (0, 1000] Hz, ~horizon = %g [0, 2] s, ~max_age = %g > 0 s, "
                "~max_future = %g [0, 60] s, ~realtime_priority = %d [0, 99], ~max_dead_reckoning = %g > 0 m, "
                "~estimate_age_floor = %g [0, ~max_age] s", rate_, horizon_, max_age_, max_future_,
                realtime_priority_, max_dead_reckoning_, estimate_age_floor_);
      ros::shutdown();
      return;
    }
    wheelbase_ = wheelbase;
    ratio_ = ratio;
    max_delta_ = max_angle * ratio;
    core_.reset(new ql::Predictor(wheelbase, ratio, max_delta_));
    // In lockstep (sim.launch lockstep:=true) inputs and the timer run in the simulator's rounds.
    pub_ = lockstep_.advertise<nav_msgs::Odometry>("localization/predicted", 10);
    sub_odom_ = lockstep_.subscribe("localization/odom", 10, &PredictorNode::onOdom, this);
    sub_state_ = lockstep_.subscribe("vehicle/state", 100, &PredictorNode::onState, this);
    sub_cal_ = lockstep_.subscribe("localization/calibration", 2, &PredictorNode::onCalibration, this);
    if (lockstep_.enabled())
      lockstep_.addTimer(1.0 / rate_, [this]() { onTimer(ros::Time::now()); });  // in the simulator's rounds
    else if (ros::Time::isSimTime())
    {
      // In sim time the beat is a callback of /clock (see onClockTick)
      period_ns_ = static_cast<int64_t>(1e9 / rate_ + 0.5);
      sub_clock_ = nh_.subscribe("/clock", 100, &PredictorNode::onClockTick, this, ros::TransportHints().tcpNoDelay());
    }
    else
      beat_ = std::thread(&PredictorNode::beat, this);
    ROS_INFO("predictor: %g Hz, horizon %g s, wheelbase %g m%s", rate_, horizon_, wheelbase,
             beat_.joinable() ? ", on a thread of its own (wall clock)" : "");
  }

  ~PredictorNode()
  {
    stop_ = true;
    if (beat_.joinable()) beat_.join();
  }

private:
  // On the wall clock (the vehicle) the 50 Hz beat has a thread of its own that sleeps to
  // absolute deadlines and publishes itself: a roscpp timer wakes the timer manager's
  // thread, which queues the callback for the spinner's thread, two wake-ups per period
  // that a loaded machine delays. ~realtime_priority > 0 asks for SCHED_FIFO at that
  // priority (needs root or an rtprio limit; without, it says so and runs as it is).
  void beat()
  {
    if (realtime_priority_ > 0)
    {
      sched_param sp{};
      sp.sched_priority = realtime_priority_;
      const int err = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
      if (err != 0)
        ROS_WARN("predictor: no real-time priority %d for the 50 Hz beat (%s): running at normal priority "
                 "(allow it with an rtprio limit in /etc/security/limits.conf)", realtime_priority_, std::strerror(err));
      else
        ROS_INFO("predictor: the 50 Hz beat runs at real-time priority %d (SCHED_FIFO)", realtime_priority_);
    }
    const auto period = std::chrono::nanoseconds(static_cast<int64_t>(1e9 / rate_));
    auto next = std::chrono::steady_clock::now() + period;
    while (!stop_ && ros::ok())
    {
      std::this_thread::sleep_until(next);
      onTimer(ros::Time::now());
      next += period;
      const auto now = std::chrono::steady_clock::now();
      if (now > next + 5 * period) next = now + period;  // a long stall: start over, no burst
    }
  }


  // In sim time a roscpp timer costs the predictor a thread that polls the clock every
  // wall millisecond (roscpp's TimerManager cannot wait for sim time), then a handoff to
  // the spinner, and it fired a tick late (the truncation below). Here the tick that
  // reaches or passes the next multiple of the period runs the beat at once, in the
  // spinner's thread, with the tick's own time (roscpp's clock thread may not have set
  // ros::Time yet): the figure eight at factor 1 cost the predictor 0.022-0.024 CPU s per
  // sim s instead of 0.035-0.044 (runs alternated). One run per tick however many
  // periods it passed, as the timer after a stall. A tick up to
  // 1 us short of a multiple counts as on it: rospy's Time.from_sec truncates, so the
  // simulator's 10.02 s is 10.019999999 s on the wire.
  void onClockTick(const rosgraph_msgs::Clock::ConstPtr& m)
  {
    constexpr int64_t kSlack = 1000;  // [ns]
    const int64_t t = static_cast<int64_t>(m->clock.toNSec());
    if (t + kSlack < next_tick_ns_ - period_ns_)  // the clock moved back: the periods start over
      next_tick_ns_ = 0;
    if (t == 0 || t + kSlack < next_tick_ns_) return;
    next_tick_ns_ = ((t + kSlack) / period_ns_ + 1) * period_ns_;
    onTimer(m->clock);
  }

  // A stamp further ahead of the clock than ~max_future comes from a broken clock or
  // from before the clock moved back: never let it become the predictor's "now".
  bool fromFuture(const ros::Time& stamp, const char* what)
  {
    const ros::Time now = ros::Time::now();
    if (now.isZero() || stamp.toSec() <= now.toSec() + max_future_) return false;
    ++rejected_;
    ROS_WARN_THROTTLE(5.0, "predictor: dropped a %s stamped %.3f s ahead of the clock (~max_future %.2f s)", what,
                      stamp.toSec() - now.toSec(), max_future_);
    return true;
  }

  void onOdom(const nav_msgs::Odometry::ConstPtr& m)
  {
    if (fromFuture(m->header.stamp, "localization estimate")) return;
    const auto& q = m->pose.pose.orientation;
    ql::Pose2 p;
    p.x = m->pose.pose.position.x;
    p.y = m->pose.pose.position.y;
    p.theta = std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.theta))
    {
      ROS_WARN_THROTTLE(5.0, "predictor: dropped an estimate with a non-finite pose");
      return;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    core_->setEstimate(m->header.stamp.toSec(), p);
    z_ = m->pose.pose.position.z;
    covariance_ = m->pose.covariance;
  }

  void onState(const quadrivio_plc::VehicleState::ConstPtr& m)
  {
    if (m->faults & quadrivio_plc::VehicleState::FAULT_LINK) return;  // no session: values unknown
    if (fromFuture(m->header.stamp, "vehicle state")) return;
    std::lock_guard<std::mutex> lock(mutex_);
    if (!core_->addReading({ m->header.stamp.toSec(), m->wheel_speed, m->handlebar }))
      ROS_WARN_THROTTLE(5.0, "predictor: dropped a vehicle state (out of order or not finite)");
  }

  void onCalibration(const quadrivio_localization::Calibration::ConstPtr& m)
  {
    ql::ModelCalibration c;
    c.speed_scale = m->wheel_speed_scale;
    c.handlebar_offset = m->handlebar_offset;
    c.steering_gain = m->steering_gain;
    if (!std::isfinite(c.speed_scale) || !std::isfinite(c.handlebar_offset) || !std::isfinite(c.steering_gain))
      return;
    std::lock_guard<std::mutex> lock(mutex_);
    core_->setCalibration(c);
  }

  void onTimer(const ros::Time& now)
  {
    nav_msgs::Odometry out;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (now < last_now_)
      {
        ROS_WARN("predictor: ROS time moved back from %.3f s to %.3f s: forgetting the estimate and readings",
                 last_now_.toSec(), now.toSec());
        core_.reset(new ql::Predictor(wheelbase_, ratio_, max_delta_));
      }
      last_now_ = now;
      if (!core_->hasEstimate()) return;
      const double age = now.toSec() - core_->estimateTime();
      if (age < -max_future_)
      {
        ROS_WARN_THROTTLE(5.0, "predictor: the localization's estimate is %.2f s ahead of the clock: not predicting",
                          -age);
        return;
      }
      if (age > max_age_)
      {
        ROS_WARN_THROTTLE(5.0, "predictor: the localization's estimate is %.2f s old (> ~max_age %.2f s): not predicting",
                          age, max_age_);
        return;
      }
      const double target = now.toSec() + horizon_;
      double travelled = 0.0;
      const ql::Pose2 p = core_->predict(target, &travelled);
      if (age > estimate_age_floor_ && travelled > max_dead_reckoning_)
      {
        ROS_WARN_THROTTLE(5.0, "predictor: the localization's estimate is %.2f s old and the vehicle has driven "
                          "%.2f m on odometry alone since (> ~max_dead_reckoning %.2f m): not predicting",
                          age, travelled, max_dead_reckoning_);
        return;
      }
      out.header.stamp = ros::Time(target);
      out.header.frame_id = map_frame_;
      out.child_frame_id = base_frame_;
      out.pose.pose.position.x = p.x;
      out.pose.pose.position.y = p.y;
      out.pose.pose.position.z = z_;
      out.pose.pose.orientation.z = std::sin(0.5 * p.theta);
      out.pose.pose.orientation.w = std::cos(0.5 * p.theta);
      out.pose.covariance = covariance_;
      double v = 0.0, w = 0.0;
      if (core_->latest(v, w))
      {
        out.twist.twist.linear.x = v;
        out.twist.twist.angular.z = w;
      }
    }
    lockstep_.publish(pub_, out);
  }

  ros::NodeHandle nh_, pnh_;
  ros::Publisher pub_;
  ros::Subscriber sub_odom_, sub_state_, sub_cal_, sub_clock_;
  int64_t period_ns_ = 20000000, next_tick_ns_ = 0;  // the beat on /clock (sim time)
  quadrivio_runtime::Lockstep lockstep_;
  int realtime_priority_ = 0;
  std::atomic<bool> stop_{ false };
  std::thread beat_;
  std::unique_ptr<ql::Predictor> core_;
  std::mutex mutex_;
  double rate_ = 50.0, horizon_ = 0.0, max_age_ = 1.0, max_future_ = 0.5, z_ = 0.0;
  double max_dead_reckoning_ = 0.5, estimate_age_floor_ = 0.15;
  double wheelbase_ = 1.0, ratio_ = 1.0, max_delta_ = 1.0;
  ros::Time last_now_;
  unsigned long rejected_ = 0;
  boost::array<double, 36> covariance_{};
  std::string map_frame_, base_frame_;
};

int main(int argc, char** argv)
{
  ros::init(argc, argv, "predictor");
  PredictorNode node;
  if (!ros::ok()) return 1;
  ros::spin();
  return 0;
}
