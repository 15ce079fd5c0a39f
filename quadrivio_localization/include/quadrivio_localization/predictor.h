// Pose predictor of the Quadrivio ATV: the latest smoother estimate integrated forward
// with the kinematic (bicycle) model over the vehicle's wheel speed and handlebar
// readings (paper section 2.2). ROS-free; the node (src/predictor_node.cpp) wires it.
//
//   x' = k_v v cos(theta),  y' = k_v v sin(theta),  theta' = k_v v tan(delta) / L,
//   delta = k_d * ratio * (h + h_0)
//
// with calibration (k_v, h_0, k_d) from the smoother's self-calibration. Between readings
// the previous reading is held (zero-order hold, as the PLC reports at 50 Hz); past the
// newest reading the last one is extrapolated.
#pragma once

#include <cmath>
#include <deque>

namespace quadrivio_localization
{
struct Pose2
{
  double x = 0.0, y = 0.0, theta = 0.0;
};

struct Reading
{
  double t;          // [s]
  double speed;      // [m/s] measured rear wheel speed
  double handlebar;  // [rad] measured handlebar angle
};

struct ModelCalibration
{
  double speed_scale = 1.0;       // k_v
  double handlebar_offset = 0.0;  // h_0 [rad]
  double steering_gain = 1.0;     // k_d
};

class Predictor
{
public:
  // max_delta: the virtual wheel angle limit [rad] (handlebar limit x ratio, vehicle.yaml), as
  // quadrivio_description.kinematics.arc clamps it.
  Predictor(double wheelbase, double ratio, double max_delta)
    : L_(wheelbase), ratio_(ratio), max_delta_(max_delta) {}

  void setCalibration(const ModelCalibration& c) { cal_ = c; }
  const ModelCalibration& calibration() const { return cal_; }

  // A smoother estimate, valid at time t.
  void setEstimate(double t, const Pose2& pose)
  {
    est_t_ = t;
    est_ = pose;
    have_estimate_ = true;
  }
  bool hasEstimate() const { return have_estimate_; }
  double estimateTime() const { return est_t_; }

  // Readings must come in time order; older ones than keep_ seconds are dropped.
  bool addReading(const Reading& r)
  {
    if (!std::isfinite(r.t) || !std::isfinite(r.speed) || !std::isfinite(r.handlebar)) return false;
    if (!readings_.empty() && r.t < readings_.back().t) return false;
    readings_.push_back(r);
    while (readings_.size() > 2 && readings_[1].t < r.t - keep_) readings_.pop_front();
    return true;
  }
  const std::deque<Reading>& readings() const { return readings_; }

  // One exact arc of the bicycle model for constant speed and handlebar over dt.
  Pose2 step(const Pose2& p, double speed, double handlebar, double dt) const
  {
    const double v = cal_.speed_scale * speed;
    double delta = cal_.steering_gain * ratio_ * (handlebar + cal_.handlebar_offset);
    delta = std::max(-max_delta_, std::min(max_delta_, delta));
    const double w = v * std::tan(delta) / L_;
    const double dth = w * dt;
    Pose2 out;
    if (std::fabs(dth) < 1e-9)
    {
      out.x = p.x + v * dt * std::cos(p.theta + 0.5 * dth);
      out.y = p.y + v * dt * std::sin(p.theta + 0.5 * dth);
    }
    else
    {
      const double r = v / w;
      out.x = p.x + r * (std::sin(p.theta + dth) - std::sin(p.theta));
      out.y = p.y - r * (std::cos(p.theta + dth) - std::cos(p.theta));
    }
    out.theta = p.theta + dth;
    return out;
  }

  // The estimate carried from its time to `target`; `travelled` (if given): the distance
  // driven on odometry alone to get there [m], what a stale estimate costs.
  Pose2 predict(double target, double* travelled = nullptr) const
  {
    Pose2 p = est_;
    double t = est_t_;
    if (travelled) *travelled = 0.0;
    if (target <= t || readings_.empty()) return p;
    // Reading in force at t: the newest one not after t (or the first one).
    size_t i = 0;
    while (i + 1 < readings_.size() && readings_[i + 1].t <= t) ++i;
    while (t < target)
    {
      // Hold reading i until the next one (or the target), then move on.
      const double next = (i + 1 < readings_.size()) ? std::max(t, std::min(target, readings_[i + 1].t)) : target;
      p = step(p, readings_[i].speed, readings_[i].handlebar, next - t);
      if (travelled) *travelled += std::fabs(cal_.speed_scale * readings_[i].speed) * (next - t);
      t = next;
      if (i + 1 < readings_.size() && t >= readings_[i + 1].t) ++i;
    }
    return p;
  }

  // Newest reading (speed, yaw rate) for the twist.
  bool latest(double& speed, double& yaw_rate) const
  {
    if (readings_.empty()) return false;
    const Reading& r = readings_.back();
    speed = cal_.speed_scale * r.speed;
    const double delta = std::max(-max_delta_, std::min(max_delta_, cal_.steering_gain * ratio_ *
                                                                     (r.handlebar + cal_.handlebar_offset)));
    yaw_rate = speed * std::tan(delta) / L_;
    return true;
  }

private:
  double L_, ratio_, max_delta_;
  double keep_ = 10.0;  // [s] of readings kept
  ModelCalibration cal_;
  std::deque<Reading> readings_;
  Pose2 est_;
  double est_t_ = 0.0;
  bool have_estimate_ = false;
};

}  // namespace quadrivio_localization
