// guard_cpp: the obstacle guard in roscpp, the protective stop between the follower and the
// PLCClient. The same node as the Python guard (quadrivio_navigation/ros/guard_node.py: read
// its docstring for the topics, the fields and the bad input it refuses), on the same core
// computation (quadrivio_navigation/guard_core.h, cross-tested against guard.py), for a
// fraction of the CPU: receiving its 315 messages a second costs rospy alone about 0.03 CPU
// seconds per second, the whole budget of the guard.
//
// Its configuration is read and checked by the Python guard's own code, once at start:
// `python3 -m quadrivio_navigation.ros.guard_config --node <this node>` (the private
// parameters, the scenario's guard: section, ~zone_file, the vehicle, the scenario's terrain).
//
// Subscribes: vehicle/setpoint/request (quadrivio_plc/Setpoint), each scanner's topic
// (sensor_msgs/LaserScan), vehicle/state (quadrivio_plc/VehicleState), imu/data
// (sensor_msgs/Imu), localization/predicted (nav_msgs/Odometry; with an operating zone or a
// DEM), /tf_static (tf2_msgs/TFMessage: the scanners' mounts).
// Publishes: vehicle/setpoint/auto (quadrivio_plc/Setpoint), guard/status
// (quadrivio_navigation/GuardStatus), /diagnostics (diagnostic_msgs/DiagnosticArray, 1 Hz).
#include <quadrivio_navigation/guard_core.h>
#include <quadrivio_runtime/lockstep.h>

#include <diagnostic_msgs/DiagnosticArray.h>
#include <nav_msgs/Odometry.h>
#include <quadrivio_navigation/GuardStatus.h>
#include <quadrivio_plc/Setpoint.h>
#include <quadrivio_plc/VehicleState.h>
#include <ros/ros.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2_msgs/TFMessage.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace g = quadrivio_navigation::guard;
using quadrivio_navigation::GuardStatus;

namespace
{
constexpr double kMaxRange = 20.0;  // [m] returns beyond this cannot matter for the fields

// Counts of rejected inputs by (input, reason), as quadrivio_runtime.guards.InputGuard
class InputGuard
{
public:
  explicit InputGuard(double max_future) : max_future_(max_future) {}

  bool reject(const std::string& what, const std::string& reason, const std::string& detail = "")
  {
    ++counts_[what + ": " + reason];
    ROS_WARN_THROTTLE(5.0, "%s: %s%s; dropped", what.c_str(), reason.c_str(),
                      detail.empty() ? "" : (" (" + detail + ")").c_str());
    return false;
  }

  bool stamp(const std::string& what, double stamp, double now)
  {
    if (!std::isfinite(stamp) || stamp < 0.0)
      return reject(what, "bad stamp", g::pyfloat(stamp));
    if (now <= 0.0)
      return true;
    if (stamp > now + max_future_)
      return reject(what, "stamp from the future", g::format("%.3f s ahead of now %.3f s", stamp - now, now));
    return true;
  }

  bool check(const std::string& what, double stamp, double now, std::initializer_list<double> values)
  {
    if (!this->stamp(what, stamp, now))
      return false;
    for (double v : values)
      if (!std::isfinite(v))
        return reject(what, "value not finite", g::pyfloat(v));
    return true;
  }

  std::string summary() const
  {
    if (counts_.empty())
      return "none";
    std::string out;
    for (const auto& kv : counts_)
    {
      const size_t colon = kv.first.find(": ");
      out += (out.empty() ? "" : "; ") + kv.first.substr(0, colon) + ": " + std::to_string(kv.second) + " x " +
             kv.first.substr(colon + 2);
    }
    return out;
  }

private:
  double max_future_;
  std::map<std::string, long> counts_;
};

struct Mount
{
  double t[3] = { 0.0, 0.0, 0.0 };
  double R[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 };
};

void quatMatrix(double x, double y, double z, double w, double R[9])
{
  const double m[9] = { 1 - 2 * (y * y + z * z), 2 * (x * y - z * w),     2 * (x * z + y * w),
                        2 * (x * y + z * w),     1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                        2 * (x * z - y * w),     2 * (y * z + x * w),     1 - 2 * (x * x + y * y) };
  std::copy(m, m + 9, R);
}

void matMul(const double A[9], const double B[9], double C[9])
{
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      C[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
}
}  // namespace

class GuardNode
{
public:
  GuardNode() : nh_(), pnh_("~"), lockstep_(nh_), inputs_(0.05)
  {
    if (!readConfiguration())
      return;
    const g::Params& p = config_.params;
    inputs_ = InputGuard(p.max_future);
    g::rpyMatrix(config_.imu_rpy[0], config_.imu_rpy[1], config_.imu_rpy[2], imu_R_);  // the mount: once
    reset();
    pub_sp_ = lockstep_.advertise<quadrivio_plc::Setpoint>("vehicle/setpoint/auto", 10);
    pub_status_ = lockstep_.advertise<GuardStatus>("guard/status", 20);
    pub_diag_ = nh_.advertise<diagnostic_msgs::DiagnosticArray>("/diagnostics", 10);  // outside the loop's data flow
    subs_.push_back(lockstep_.subscribe("vehicle/setpoint/request", 10, &GuardNode::onRequest, this));
    subs_.push_back(lockstep_.subscribe("vehicle/state", 10, &GuardNode::onState, this));
    subs_.push_back(lockstep_.subscribe("imu/data", 20, &GuardNode::onImu, this));
    subs_.push_back(lockstep_.subscribe("/tf_static", 10, &GuardNode::onTfStatic, this));
    for (size_t i = 0; i < p.scanners.size(); ++i)
    {
      scan_subs_.emplace_back(new ScanSub{ this, i });
      subs_.push_back(lockstep_.subscribe(p.scanners[i].topic, 2, &ScanSub::cb, scan_subs_.back().get()));
    }
    if (!p.zone.empty() || !config_.terrain.empty())
      subs_.push_back(lockstep_.subscribe("localization/predicted", 5, &GuardNode::onPose, this));
    std::string scanners;
    for (const auto& s : p.scanners)
      scanners += (scanners.empty() ? "" : ", ") + s.topic + " (" + s.covers +
                  (s.no_return == "inf" ? "" : ", no echo reported as " + s.no_return) + ")";
    ROS_INFO("obstacle guard (roscpp): %s; brake %.1f m/s^2 after %.2f s, margins %.2f / %.2f m%s%s", scanners.c_str(),
             p.brake_decel, p.brake_latency, p.margin, p.warning_margin,
             p.zone.empty() ? "" : g::format(", operating zone of %zu vertices", p.zone.size()).c_str(),
             config_.terrain.empty() ? "" : ", the scenario's terrain is known (a DEM)");
    ok_ = true;
  }

  bool ok() const { return ok_; }

private:
  struct ScanSub
  {
    GuardNode* node;
    size_t index;
    void cb(const sensor_msgs::LaserScan::ConstPtr& m) { node->onScan(index, *m); }
  };

  bool readConfiguration()
  {
    const std::string cmd = "python3 -m quadrivio_navigation.ros.guard_config --node '" + ros::this_node::getName() + "'";
    FILE* in = popen(cmd.c_str(), "r");
    if (in == nullptr)
    {
      ROS_FATAL("guard: cannot run '%s' to read the configuration", cmd.c_str());
      ros::shutdown();
      return false;
    }
    std::string error;
    const bool read = g::readConfig(in, config_, error);
    const int status = pclose(in);
    if (!read || status != 0)
    {
      ROS_FATAL("guard: bad guard configuration (%s): %s", cmd.c_str(),
                !read ? error.c_str() : "the reader failed, see the message above");
      ros::shutdown();
      return false;
    }
    return true;
  }

  void reset()
  {
    core_.reset(new g::Guard(config_.params, config_.vehicle, &config_.terrain));
    attitude_ = g::Attitude(config_.params.slope_tau, 8.0, 0.25, 0.05, config_.imu_xyz);
    has_request_ = false;
    has_last_action_ = false;
    has_pose_ = false;
  }

  // ROS time now; when it moved back (the simulator's ~reset) the guard starts over
  double now()
  {
    const double t = ros::Time::now().toSec();
    if (t + 1e-3 < last_now_)
    {
      ROS_WARN("guard: ROS time moved back from %.3f s to %.3f s: starting over", last_now_, t);
      reset();
    }
    last_now_ = t;
    return t;
  }

  // ------------------------------------------------------------ inputs
  void onState(const quadrivio_plc::VehicleState::ConstPtr& m)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const double t = now(), stamp = m->header.stamp.toSec();
    if (!inputs_.check("vehicle/state", stamp, t, { m->wheel_speed, m->handlebar }))
      return;
    core_->onState(stamp, m->wheel_speed, m->handlebar);
    attitude_.addSpeed(stamp, m->wheel_speed);
    diagnose(t);
  }

  void onImu(const sensor_msgs::Imu::ConstPtr& m)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const double t = now(), stamp = m->header.stamp.toSec();
    const auto& a = m->linear_acceleration;
    const auto& w = m->angular_velocity;
    if (!inputs_.check("imu/data", stamp, t, { a.x, a.y, a.z, w.x, w.y, w.z }))
      return;
    const double* R = imu_R_;
    const double f[3] = { R[0] * a.x + R[1] * a.y + R[2] * a.z, R[3] * a.x + R[4] * a.y + R[5] * a.z,
                          R[6] * a.x + R[7] * a.y + R[8] * a.z };
    const double r[3] = { R[0] * w.x + R[1] * w.y + R[2] * w.z, R[3] * w.x + R[4] * w.y + R[5] * w.z,
                          R[6] * w.x + R[7] * w.y + R[8] * w.z };
    attitude_.addImu(stamp, f, r);
    core_->onPitch(stamp, attitude_.pitch);
  }

  void onPose(const nav_msgs::Odometry::ConstPtr& m)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const double t = now(), stamp = m->header.stamp.toSec();
    const auto& p = m->pose.pose.position;
    const auto& q = m->pose.pose.orientation;
    const auto& c = m->pose.covariance;
    if (!inputs_.check("localization/predicted", stamp, t, { p.x, p.y, q.z, q.w, c[0], c[7] }))
      return;
    const double sd = std::sqrt(std::max({ c[0], c[7], 0.0 }));
    const double yaw = std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
    has_pose_ = true;
    pose_[0] = stamp;
    pose_[1] = p.x;
    pose_[2] = p.y;
    pose_[3] = yaw;
    pose_[4] = sd;
    core_->onPose(stamp, p.x, p.y, yaw, sd);
  }

  void onTfStatic(const tf2_msgs::TFMessage::ConstPtr& m)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& t : m->transforms)
      static_[t.child_frame_id] = t;
    mounts_.clear();
  }

  // ``frame`` in the base frame through /tf_static; false if it is not on it
  bool mount(const std::string& frame, Mount& out)
  {
    auto it = mounts_.find(frame);
    if (it != mounts_.end())
    {
      out = it->second;
      return true;
    }
    Mount m;
    std::string f = frame;
    for (int i = 0; i < 32; ++i)
    {
      if (f == config_.base_frame)
      {
        mounts_[frame] = m;
        out = m;
        return true;
      }
      auto s = static_.find(f);
      if (s == static_.end())
        return false;
      const auto& q = s->second.transform.rotation;
      const auto& p = s->second.transform.translation;
      double Rp[9], R[9];
      quatMatrix(q.x, q.y, q.z, q.w, Rp);
      matMul(Rp, m.R, R);
      const double t[3] = { Rp[0] * m.t[0] + Rp[1] * m.t[1] + Rp[2] * m.t[2] + p.x,
                            Rp[3] * m.t[0] + Rp[4] * m.t[1] + Rp[5] * m.t[2] + p.y,
                            Rp[6] * m.t[0] + Rp[7] * m.t[1] + Rp[8] * m.t[2] + p.z };
      std::copy(R, R + 9, m.R);
      std::copy(t, t + 3, m.t);
      f = s->second.header.frame_id;
    }
    return false;
  }

  // Which rays lie on the DEM (empty: no DEM, or no fresh pose)
  std::vector<char> ground(const sensor_msgs::LaserScan& m, const Mount& mt, double t)
  {
    if (config_.terrain.empty() || !has_pose_ || t - pose_[0] > 0.5)
      return {};
    double Rmap[9], R[9];
    g::rpyMatrix(attitude_.roll, attitude_.pitch, pose_[3], Rmap);
    matMul(Rmap, mt.R, R);
    // base_link on its wheels, its height as uncertain as the returns' (local_layer.terrain_ground)
    const double slack = config_.ground_position_sigmas * std::max(pose_[4], config_.ground_position_sd_min);
    double grad = 0.0;
    const double z0 = config_.wheels.empty() ?
                          config_.terrain.height(pose_[1], pose_[2]) + config_.wheel_radius :
                          g::baseOnWheels(config_.terrain, pose_[1], pose_[2], Rmap, config_.wheel_radius,
                                          config_.wheels, &grad);
    double pos[3] = { pose_[1], pose_[2], z0 };
    const double tb[3] = { mt.t[0], mt.t[1], mt.t[2] };
    for (int i = 0; i < 3; ++i)
      pos[i] += Rmap[3 * i] * tb[0] + Rmap[3 * i + 1] * tb[1] + Rmap[3 * i + 2] * tb[2];
    int n = 0;
    auto out = g::demGround(config_.terrain, pos, R, m.ranges, m.angle_min, m.angle_increment, m.range_min,
                            m.range_max, kMaxRange, config_.ground_tolerance + slack * grad, &n, 0.0, slack,
                            config_.ground_tolerance_max);
    ground_returns_ += n;
    return out;
  }

  void onScan(size_t index, const sensor_msgs::LaserScan& m)
  {
    std::unique_lock<std::mutex> lock(mutex_);
    const g::Scanner& s = config_.params.scanners[index];
    const double t = now(), stamp = m.header.stamp.toSec();
    std::string frame = m.header.frame_id;
    if (!frame.empty() && frame[0] == '/')
      frame = frame.substr(frame.find_first_not_of('/'));
    if (frame != s.frame)
    {
      inputs_.reject(s.topic, "wrong frame_id", "'" + m.header.frame_id + "', expected '" + s.frame + "'");
      return;
    }
    if (!inputs_.stamp(s.topic, stamp, t))
      return;
    if (t - stamp > config_.params.max_scan_age)
    {
      inputs_.reject(s.topic, "stale scan",
                     g::format("%.3f s old (> %s s)", t - stamp, g::pyfloat(config_.params.max_scan_age).c_str()));
      return;
    }
    const std::string bad =
        g::checkScan(m.ranges.size(), m.angle_min, m.angle_max, m.angle_increment, m.range_min, m.range_max);
    if (!bad.empty())
    {
      inputs_.reject(s.topic, "malformed scan", bad);
      return;
    }
    Mount mt;
    if (!mount(s.frame, mt))
      core_->onScan(index, stamp, nullptr, "no transform " + config_.base_frame + " <- " + s.frame + " on /tf_static");
    else
    {
      const sensor_msgs::LaserScan* scan = &m;
      if (s.no_return != "inf")  // the driver's "nothing seen" as REP 117's +inf (a copy: the message is shared)
      {
        decoded_ = m;
        g::rep117Ranges(decoded_.ranges, m.range_max, s.no_return);
        scan = &decoded_;
      }
      const std::vector<char> on_ground = ground(*scan, mt, t);
      const g::ScanPoints pts =
          g::scanPoints(scan->ranges, m.angle_min, m.angle_increment, m.range_min, m.range_max, mt.t[0], mt.t[1],
                        std::atan2(mt.R[3], mt.R[0]), kMaxRange, mt.R, on_ground.empty() ? nullptr : &on_ground);
      core_->onScan(index, stamp, &pts);
    }
    const bool fresh = has_request_ && t - request_[0] <= config_.request_timeout;
    const double speed = fresh ? request_[1] : 0.0, handlebar = fresh ? request_[2] : 0.0,
                 brake = fresh ? request_[3] : 0.0;
    const g::Decision d = core_->decide(t, speed, handlebar);
    const bool stop_now = fresh && (d.action == g::STOP || d.action == g::FAULT) &&
                          !(has_last_action_ && (last_action_ == g::STOP || last_action_ == g::FAULT));
    const g::Setpoint sp = core_->command(d, speed, handlebar, brake);
    const int before = has_last_action_ ? last_action_ : -1;
    last_action_ = d.action;
    has_last_action_ = true;
    if (stop_now)  // at once: the next request may be 20 ms away
      send(sp, ros::Time(t));
    status(d, speed, sp.speed, before, handlebar);
    diagnose(t);
  }

  void onRequest(const quadrivio_plc::Setpoint::ConstPtr& m)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const double t = now();
    if (!inputs_.check("vehicle/setpoint/request", m->header.stamp.toSec(), t, { m->speed, m->handlebar, m->brake }))
      return;
    has_request_ = true;
    request_[0] = t;
    request_[1] = m->speed;
    request_[2] = m->handlebar;
    request_[3] = m->brake;
    const g::Decision d = core_->decide(t, m->speed, m->handlebar);
    const g::Setpoint sp = core_->command(d, m->speed, m->handlebar, m->brake);
    const int before = has_last_action_ ? last_action_ : -1;
    last_action_ = d.action;
    has_last_action_ = true;
    send(sp, m->header.stamp);
    if (d.action != before)
      status(d, m->speed, sp.speed, before, m->handlebar);
    diagnose(t);
  }

  // ------------------------------------------------------------ outputs
  void send(const g::Setpoint& sp, const ros::Time& stamp)
  {
    quadrivio_plc::Setpoint out;
    out.header.stamp = stamp;
    out.speed = sp.speed;
    out.handlebar = sp.handlebar;
    out.brake = sp.brake;
    lockstep_.publish(pub_sp_, out);
  }

  void status(const g::Decision& d, double requested, double commanded, int before, double handlebar)
  {
    GuardStatus m;
    m.header.stamp = ros::Time::now();
    m.header.frame_id = config_.base_frame;
    m.action = static_cast<uint8_t>(d.action);
    m.field = d.field;
    m.reason = d.reason;
    m.speed_limit = d.limit;
    m.requested_speed = requested;
    m.commanded_speed = commanded;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    m.measured_speed = core_->hasState() ? core_->stateSpeed() : nan;
    m.requested_handlebar = handlebar;
    m.measured_handlebar = core_->hasState() ? core_->stateHandlebar() : nan;
    m.free_distance = d.free;
    m.protective_distance = d.protective;
    m.warning_distance = d.warning;
    m.has_nearest = d.has_nearest;
    if (d.has_nearest)
    {
      m.nearest.x = d.nearest.x;
      m.nearest.y = d.nearest.y;
    }
    m.scanner = d.scanner;
    if (std::isfinite(d.scan_stamp))
      m.scan_stamp = ros::Time(d.scan_stamp);
    m.direction = static_cast<int8_t>(d.direction);
    m.slope = d.slope;
    m.protective_stops = static_cast<uint32_t>(core_->protective_stops);
    lockstep_.publish(pub_status_, m);
    if (log_.worth(now(), d.action, before, d.reason))
    {
      const std::string text = std::string("guard ") + g::actionName(d.action) + (d.reason.empty() ? "" : ": ") +
                               d.reason;
      if (d.action == g::FAULT)
        ROS_ERROR("%s", text.c_str());
      else if (d.action == g::STOP || d.action == g::HOLD)
        ROS_WARN("%s", text.c_str());
      else
        ROS_INFO("%s", text.c_str());
    }
  }

  // /diagnostics once a simulated second, from the inputs' callbacks (no timer thread)
  void diagnose(double t)
  {
    if (t < next_diag_ && t + 1e-3 >= next_diag_ - 1.0)
      return;
    next_diag_ = t + 1.0;
    diagnostic_msgs::DiagnosticStatus st;
    st.name = ros::this_node::getName().substr(1) + ": obstacle guard";
    st.hardware_id = "obstacle guard";
    auto add = [&st](const std::string& k, const std::string& v) {
      diagnostic_msgs::KeyValue kv;
      kv.key = k;
      kv.value = v;
      st.values.push_back(kv);
    };
    if (!core_->hasLast())
    {
      st.level = diagnostic_msgs::DiagnosticStatus::OK;
      st.message = "no request yet";
    }
    else
    {
      const g::Decision& d = core_->last();
      static const uint8_t levels[] = { diagnostic_msgs::DiagnosticStatus::OK, diagnostic_msgs::DiagnosticStatus::OK,
                                        diagnostic_msgs::DiagnosticStatus::WARN,
                                        diagnostic_msgs::DiagnosticStatus::WARN,
                                        diagnostic_msgs::DiagnosticStatus::ERROR };
      st.level = levels[d.action];
      st.message = std::string(g::actionName(d.action)) + (d.reason.empty() ? "" : ": " + d.reason);
      add("field", d.field.empty() ? "none" : d.field);
      add("free distance [m]", g::format("%.2f", d.free));
      add("protective field [m]", g::format("%.2f", d.protective));
      add("warning field [m]", g::format("%.2f", d.warning));
      add("speed limit [m/s]", g::format("%.2f", d.limit));
      add("nearest point (base_link) [m]",
          d.has_nearest ? g::format("%.2f, %.2f (%s)", d.nearest.x, d.nearest.y, d.scanner.c_str()) : "none");
      add("slope used [deg]", g::format("%.1f", d.slope * 180.0 / M_PI));
    }
    add("protective stops", std::to_string(core_->protective_stops));
    add("fail-safe stops", std::to_string(core_->fault_stops));
    add("zone stops", std::to_string(core_->zone_stops));
    std::string tracked;
    for (size_t i = 0; i < config_.params.scanners.size(); ++i)
    {
      const g::MotionTracker& tr = core_->tracker(i);
      tracked += g::format("%s%s: %d moving of %zu tracked", i ? ", " : "", config_.params.scanners[i].topic.c_str(),
                           tr.prediction.moving, tr.tracks().size());
    }
    add("moving obstacles", tracked);
    // tracks whose centroid slid like a moving thing's, refused for want of seen-through evidence
    std::string refused;
    for (size_t i = 0; i < config_.params.scanners.size(); ++i)
      refused += g::format("%s%s: %ld", i ? ", " : "", config_.params.scanners[i].topic.c_str(),
                           core_->tracker(i).refused);
    add("standing things refused as moving", refused);
    add("ground returns (DEM)", config_.terrain.empty() ? "no DEM" : std::to_string(ground_returns_));
    add("inputs rejected", inputs_.summary());
    diagnostic_msgs::DiagnosticArray a;
    a.header.stamp = ros::Time::now();
    a.status.push_back(st);
    pub_diag_.publish(a);
  }

  ros::NodeHandle nh_, pnh_;
  quadrivio_runtime::Lockstep lockstep_;
  g::Config config_;
  InputGuard inputs_;
  std::unique_ptr<g::Guard> core_;
  g::Attitude attitude_;
  std::mutex mutex_;
  ros::Publisher pub_sp_, pub_status_, pub_diag_;
  std::vector<ros::Subscriber> subs_;
  std::vector<std::unique_ptr<ScanSub>> scan_subs_;
  std::map<std::string, geometry_msgs::TransformStamped> static_;
  std::map<std::string, Mount> mounts_;
  sensor_msgs::LaserScan decoded_;  // a scan whose driver is not REP 117's, its ranges made so
  g::DecisionLog log_;              // which decisions are logged
  bool ok_ = false, has_request_ = false, has_last_action_ = false, has_pose_ = false;
  double request_[4] = { 0, 0, 0, 0 }, pose_[5] = { 0, 0, 0, 0, 0 };  // stamp, x, y, yaw, horizontal sd
  int last_action_ = 0;
  long ground_returns_ = 0;
  double last_now_ = 0.0, next_diag_ = 0.0;
  double imu_R_[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 };  // the IMU's mount in base_link
};

int main(int argc, char** argv)
{
  ros::init(argc, argv, "guard");
  GuardNode node;
  if (!node.ok())
    return 1;
  ros::spin();
  return 0;
}
