// The obstacle guard's core in C++: the same computation as the Python reference
// (quadrivio_navigation/guard.py, fields.py, attitude.py, local_layer.dem_ground), for the
// roscpp guard node, whose inputs (315 messages a second) rospy alone cannot receive within
// the guard's CPU budget. ROS-free and header-only; cross-tested against the Python core on
// random cases (test/test_guard_native.py through the guard_replay driver): read the Python
// modules' docstrings for the fields, the stop/hold/release cycle and the zone.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace quadrivio_navigation
{
namespace guard
{
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kGravity = 9.81;  // quadrivio_description.vehicle.GRAVITY (the cross-test holds them equal)

enum Action
{
  CLEAR = 0,
  SLOW = 1,
  STOP = 2,
  HOLD = 3,
  FAULT = 4
};

inline const char* actionName(int a)
{
  static const char* names[] = { "CLEAR", "SLOW", "STOP", "HOLD", "FAULT" };
  return a >= 0 && a <= 4 ? names[a] : "?";
}

// Which decisions the node logs (guard.DecisionLog): a change of action, but not between
// CLEAR and SLOW nor into the first; and a FAULT that lasts, again every kFaultRelog s while its
// reason is not the one logged (a laser that comes back blinded: still stopped, for another
// reason; and a FAULT from the start, once it has lasted kFaultRelog).
constexpr double kFaultRelog = 5.0;  // [s]

class DecisionLog
{
public:
  // ``before``: the previous action, -1 for none
  bool worth(double now, int action, int before, const std::string& reason)
  {
    if (!started_)
    {
      started_ = true;
      t_ = now;
    }
    if (before < 0)
      return false;
    bool ok;
    if (action != before)
      ok = !((action == SLOW && before == CLEAR) || (action == CLEAR && before == SLOW));
    else
      ok = action == FAULT && reason != reason_ && now - t_ >= kFaultRelog;
    if (ok)
    {
      reason_ = reason;
      t_ = now;
    }
    return ok;
  }

private:
  bool started_ = false;
  double t_ = 0.0;
  std::string reason_;
};

// printf into a std::string (the reasons carry the same text as the Python guard's)
template <typename... Args>
std::string format(const char* fmt, Args... args)
{
  char buf[512];
  std::snprintf(buf, sizeof(buf), fmt, args...);
  return buf;
}

// A float as Python's repr prints it (0.2, 1.0, 0.35): the parameters in the reasons read as
// the Python guard's do
inline std::string pyfloat(double x)
{
  if (std::isnan(x))
    return "nan";
  if (std::isinf(x))
    return x > 0 ? "inf" : "-inf";
  char buf[40];
  for (int prec = 1; prec <= 17; ++prec)
  {
    std::snprintf(buf, sizeof(buf), "%.*g", prec, x);
    if (std::strtod(buf, nullptr) == x)
      break;
  }
  std::string out(buf);
  if (out.find_first_of(".en") == std::string::npos)
    out += ".0";
  return out;
}

struct Point
{
  double x = 0.0, y = 0.0;
};

// The vehicle's rectangle about base_link [m] (quadrivio_navigation.costmap.Footprint)
struct Footprint
{
  double front = 0.0, rear = 0.0, left = 0.0, right = 0.0;
  double circumscribedRadius() const { return std::hypot(std::max(front, rear), std::max(left, right)); }
  bool contains(double u, double w) const { return u <= front && u >= -rear && w <= left && w >= -right; }
  Footprint grown(double g) const { return Footprint{ front + g, rear + g, left + g, right + g }; }
  std::array<Point, 4> corners(double x, double y, double th) const
  {
    const double c = std::cos(th), s = std::sin(th);
    const double local[4][2] = { { front, -right }, { front, left }, { -rear, left }, { -rear, -right } };
    std::array<Point, 4> out;
    for (int i = 0; i < 4; ++i)
      out[i] = Point{ x + c * local[i][0] - s * local[i][1], y + s * local[i][0] + c * local[i][1] };
    return out;
  }
};

// ---------------------------------------------------------------- fields (fields.py)
// How far each ray saw empty space (fields.Rays): a ray at angle a in the laser's plane points
// along (m00 cos a + m01 sin a, m10 cos a + m11 sin a) in base_link's x-y plane, from (ox, oy)
struct Rays
{
  double ox = 0.0, oy = 0.0, m00 = 1.0, m01 = 0.0, m10 = 0.0, m11 = 1.0, angle_min = 0.0, inc = 0.0;
  std::vector<double> free;  // [m] the return's range (-inf: range_min); range_max for +inf; NaN (unknown) else
};

struct ScanPoints
{
  std::vector<Point> xy;  // base_link
  int n_rays = 0, n_invalid = 0, n_too_close = 0;
  int n_zero = 0, n_beyond = 0;  // of the invalid: exactly 0.0 below range_min; finite beyond range_max
  bool has_rays = false;  // false: the points alone (no test of what was seen through)
  Rays rays;
};

// A driver's ranges in REP 117's terms (fields.rep117_ranges): the rays it reports as having
// seen nothing in its own way ``no_return`` become +inf: "inf" (REP 117: nothing changes),
// "zero" (exactly 0.0), "beyond_max" (finite beyond range_max). "" or what is wrong.
inline std::string rep117Ranges(std::vector<float>& ranges, double rmax, const std::string& no_return)
{
  const float inf = std::numeric_limits<float>::infinity();
  if (no_return == "inf")
    return "";
  if (no_return == "zero")
  {
    for (float& r : ranges)
      if (r == 0.0f)
        r = inf;
    return "";
  }
  if (no_return == "beyond_max")
  {
    for (float& r : ranges)
      if (std::isfinite(r) && static_cast<double>(r) > rmax)
        r = inf;
    return "";
  }
  return "no_return '" + no_return + "': expected one of inf, zero, beyond_max";
}

// The blinded stop's reason (fields.blinded_reason, word for word)
inline std::string blindedReason(const std::string& topic, int n_rays, int n_invalid, int n_zero, int n_beyond)
{
  const double n = std::max(n_rays, 1);
  std::string out = format("%s blinded: %.0f %% of its rays invalid", topic.c_str(), 100.0 * n_invalid / n);
  if (2 * n_zero > n_invalid)
    out += format(", %.0f %% read 0 m: a driver that reports no echo so needs the scanner's no_return: zero",
                  100.0 * n_zero / n);
  else if (2 * n_beyond > n_invalid)
    out += format(", %.0f %% beyond range_max: a driver that reports no echo so needs the scanner's "
                  "no_return: beyond_max",
                  100.0 * n_beyond / n);
  return out;
}

// "" or what is wrong with a scan's geometry (fields.check_scan)
inline std::string checkScan(size_t n, double angle_min, double angle_max, double inc, double rmin, double rmax)
{
  if (!(std::isfinite(angle_min) && std::isfinite(angle_max) && std::isfinite(inc) && std::isfinite(rmin) &&
        std::isfinite(rmax)))
    return format("non-finite geometry (angle_min %g, angle_max %g, angle_increment %g, range_min %g, range_max %g)",
                  angle_min, angle_max, inc, rmin, rmax);
  if (inc == 0.0)
    return "angle_increment is 0";
  if (!(0.0 <= rmin && rmin < rmax))
    return format("range_min %g m and range_max %g m are not 0 <= min < max", rmin, rmax);
  if (n < 1)
    return "no ranges";
  const long expected = std::lround((angle_max - angle_min) / inc) + 1;
  if (std::labs(expected - static_cast<long>(n)) > 1)
    return format("%zu ranges, but angle_min %.4f, angle_max %.4f and angle_increment %.6f rad make %ld", n, angle_min,
                  angle_max, inc, expected);
  return "";
}

// The scan's returns in base_link (REP 117: NaN invalid, +inf nothing, -inf at range_min);
// ``rot`` (row-major 3 x 3 into base_link) or, when null, the mount's yaw; ``ground[i]``
// true: ray i hit the ground (taken as +inf).
inline ScanPoints scanPoints(const std::vector<float>& ranges, double angle_min, double inc, double rmin, double rmax,
                             double mx, double my, double myaw, double max_range, const double* rot,
                             const std::vector<char>* ground = nullptr)
{
  ScanPoints out;
  out.n_rays = static_cast<int>(ranges.size());
  out.xy.reserve(ranges.size());
  out.has_rays = true;
  Rays& rays = out.rays;
  rays.ox = mx;
  rays.oy = my;
  if (rot == nullptr)
  {
    const double c = std::cos(myaw), s = std::sin(myaw);
    rays.m00 = c;
    rays.m01 = -s;
    rays.m10 = s;
    rays.m11 = c;
  }
  else
  {
    rays.m00 = rot[0];
    rays.m01 = rot[1];
    rays.m10 = rot[3];
    rays.m11 = rot[4];
  }
  rays.angle_min = angle_min;
  rays.inc = inc;
  rays.free.assign(ranges.size(), std::numeric_limits<double>::quiet_NaN());
  for (size_t i = 0; i < ranges.size(); ++i)
  {
    double r = ranges[i];
    if (ground != nullptr && (*ground)[i])
      r = kInf;
    if (std::isnan(r))
    {
      ++out.n_invalid;
      continue;
    }
    bool too_close = std::isinf(r) && r < 0.0;
    if (too_close)
    {
      ++out.n_too_close;
      r = rmin;
    }
    else if (std::isinf(r))
    {
      rays.free[i] = rmax;
      continue;
    }
    else if (r < rmin || r > rmax)
    {
      ++out.n_invalid;
      out.n_zero += r == 0.0;
      out.n_beyond += r > rmax;
      continue;
    }
    rays.free[i] = r;  // -inf: a return at range_min
    if (r > max_range)
      continue;
    double dx, dy;
    if (rot == nullptr)
    {
      const double a = angle_min + inc * static_cast<double>(i) + myaw;
      dx = std::cos(a);
      dy = std::sin(a);
    }
    else
    {
      const double a = angle_min + inc * static_cast<double>(i);
      const double c = std::cos(a), s = std::sin(a);
      dx = rot[0] * c + rot[1] * s;
      dy = rot[3] * c + rot[4] * s;
    }
    out.xy.push_back(Point{ mx + r * dx, my + r * dy });
  }
  return out;
}

struct Pose2
{
  double x = 0.0, y = 0.0, th = 0.0;
};

// Poses every ``ds`` along the next ``length`` metres (fields.sweep); the first is 0
inline std::vector<Pose2> sweep(int dir, double h0, double h1, double rate, double speed, double length, double ds,
                                double wheelbase, double ratio)
{
  const int k = std::max(1, static_cast<int>(std::ceil(length / ds)));
  std::vector<Pose2> out(static_cast<size_t>(k) + 1);
  const double v = std::max(std::fabs(speed), 0.3);
  double x = 0.0, y = 0.0, th = 0.0;
  for (int i = 0; i < k; ++i)
  {
    const double t = ds * i / v;
    const double h = h0 + std::min(std::max(h1 - h0, -rate * t), rate * t);
    const double dth = dir * (std::tan(ratio * h) / wheelbase) * ds;
    const double mid = th + 0.5 * dth;
    x += dir * std::cos(mid) * ds;
    y += dir * std::sin(mid) * ds;
    th += dth;
    out[static_cast<size_t>(i) + 1] = Pose2{ x, y, th };
  }
  return out;
}

struct Free
{
  double distance = kInf;
  bool has_point = false;
  Point point;
  int index = -1;
};

// Distance along ``poses`` before the footprint first holds a point (fields.free_distance)
inline Free freeDistance(const Footprint& fp, const std::vector<Pose2>& poses, const std::vector<Point>& pts, double ds)
{
  Free out;
  if (pts.empty())
    return out;
  double far = 0.0;
  for (const auto& p : poses)
    far = std::max(far, std::hypot(p.x, p.y));
  const double reach = fp.circumscribedRadius() + far;
  std::vector<int> near;
  for (size_t j = 0; j < pts.size(); ++j)
    if (pts[j].x * pts[j].x + pts[j].y * pts[j].y <= reach * reach)
      near.push_back(static_cast<int>(j));
  if (near.empty())
    return out;
  for (size_t k = 0; k < poses.size(); ++k)
  {
    const double c = std::cos(poses[k].th), s = std::sin(poses[k].th);
    for (int j : near)
    {
      const double dx = pts[j].x - poses[k].x, dy = pts[j].y - poses[k].y;
      if (fp.contains(c * dx + s * dy, -s * dx + c * dy))
      {
        out.distance = std::max(0.0, (static_cast<double>(k) - 1.0) * ds);
        out.has_point = true;
        out.point = pts[j];
        out.index = j;
        return out;
      }
    }
  }
  return out;
}

inline double effectiveDecel(double decel, double slope, double floor = 0.3)
{
  return std::max(decel - kGravity * std::sin(slope), floor);
}

inline double stoppingDistance(double speed, double reaction, double decel)
{
  const double v = std::fabs(speed);
  return v * reaction + v * v / (2.0 * decel);
}

inline double allowedSpeed(double distance, double reaction, double decel)
{
  if (distance <= 0.0)
    return 0.0;
  if (std::isinf(distance))
    return kInf;
  return decel * (-reaction + std::sqrt(reaction * reaction + 2.0 * distance / decel));
}

// Even-odd rule (guard.points_in_polygon)
inline bool inPolygon(const Point& p, const std::vector<Point>& poly)
{
  int crossings = 0;
  const size_t n = poly.size();
  for (size_t i = 0; i < n; ++i)
  {
    const Point& a = poly[i];
    const Point& b = poly[(i + 1) % n];
    if ((a.y > p.y) != (b.y > p.y))
    {
      const double xc = a.x + (p.y - a.y) * (b.x - a.x) / (b.y - a.y);
      if (p.x < xc)
        ++crossings;
    }
  }
  return crossings % 2 == 1;
}

// ---------------------------------------------------------------- attitude (attitude.py)
inline void rpyMatrix(double r, double p, double y, double R[9])
{
  const double cr = std::cos(r), sr = std::sin(r), cp = std::cos(p), sp = std::sin(p), cy = std::cos(y),
               sy = std::sin(y);
  const double m[9] = { cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, sy * cp, sy * sp * sr + cy * cr,
                        sy * sp * cr - cy * sr, -sp,     cp * sr,               cp * cr };
  std::copy(m, m + 9, R);
}

class Attitude
{
public:
  explicit Attitude(double tau = 4.0, double max_accel = 8.0, double speed_timeout = 0.25, double max_bias = 0.05,
                    const double lever[3] = nullptr)
    : tau_(tau), max_accel_(max_accel), speed_timeout_(speed_timeout), max_bias_(max_bias)
  {
    if (lever != nullptr)
      std::copy(lever, lever + 3, lever_);
  }
  double roll = 0.0, pitch = 0.0;
  double bias_roll = 0.0, bias_pitch = 0.0;  // [rad/s] learnt from the pull (attitude.py)
  bool hasImu() const { return has_t_; }
  double lastImu() const { return t_; }

  void addSpeed(double t, double v)
  {
    if (has_speed_ && t > speed_t_)
    {
      const double a = (v - speed_v_) / (t - speed_t_);
      accel_ok_ = std::fabs(a) <= max_accel_;
      accel_ = accel_ok_ ? a : 0.0;
    }
    has_speed_ = true;
    speed_t_ = t;
    speed_v_ = v;
  }

  void addImu(double t, const double f_in[3], const double w[3])
  {
    if (has_t_ && t <= t_)
      return;
    // the specific force at base_link's origin: the IMU's lever also feels w x (w x r)
    double f[3] = { f_in[0], f_in[1], f_in[2] };
    if (lever_[0] != 0.0 || lever_[1] != 0.0 || lever_[2] != 0.0)
    {
      const double wr = w[0] * lever_[0] + w[1] * lever_[1] + w[2] * lever_[2];
      const double ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
      for (int i = 0; i < 3; ++i)
        f[i] = f_in[i] - (w[i] * wr - lever_[i] * ww);
    }
    const bool fresh = has_speed_ && t - speed_t_ <= speed_timeout_;
    const double v = fresh ? speed_v_ : 0.0;
    const double gx = f[0] - (fresh ? accel_ : 0.0), gy = f[1] - v * w[2], gz = f[2];
    const double roll_g = std::atan2(gy, gz), pitch_g = std::atan2(-gx, std::hypot(gy, gz));
    if (!started_)
    {
      roll = roll_g;
      pitch = pitch_g;
      started_ = has_t_ = true;
      t_ = t;
      return;
    }
    const double dt = t - t_;
    t_ = t;
    const double sr = std::sin(roll), cr = std::cos(roll), tp = std::tan(pitch);
    roll += (w[0] + (w[1] * sr + w[2] * cr) * tp - bias_roll) * dt;
    pitch += (w[1] * cr - w[2] * sr - bias_pitch) * dt;
    if ((fresh && accel_ok_) || !has_speed_)
    {
      const double k = std::min(1.0, dt / tau_);
      const double e_roll = roll_g - roll, e_pitch = pitch_g - pitch;
      roll += k * e_roll;
      pitch += k * e_pitch;
      const double ki = dt / (4.0 * tau_ * tau_);
      bias_roll = std::min(std::max(bias_roll - ki * e_roll, -max_bias_), max_bias_);
      bias_pitch = std::min(std::max(bias_pitch - ki * e_pitch, -max_bias_), max_bias_);
    }
  }

private:
  double tau_, max_accel_, speed_timeout_, max_bias_;
  double lever_[3] = { 0.0, 0.0, 0.0 };
  bool has_t_ = false, started_ = false, has_speed_ = false, accel_ok_ = false;
  double t_ = 0.0, speed_t_ = 0.0, speed_v_ = 0.0, accel_ = 0.0;
};

// ---------------------------------------------------------------- terrain (quadrivio_terrain.Heightfield)
struct Heightfield
{
  int rows = 0, cols = 0;
  double res = 1.0, x0 = 0.0, y0 = 0.0;
  std::vector<double> z;  // row-major, row index grows with y

  bool empty() const { return z.empty(); }
  // Bilinear height; outside the grid the edge value
  double height(double x, double y) const
  {
    const double fx = std::min(std::max((x - x0) / res, 0.0), cols - 1.000001);
    const double fy = std::min(std::max((y - y0) / res, 0.0), rows - 1.000001);
    const int j = static_cast<int>(fx), i = static_cast<int>(fy);
    const double tx = fx - j, ty = fy - i;
    const double* r0 = &z[static_cast<size_t>(i) * cols];
    const double* r1 = r0 + cols;
    return (1 - ty) * ((1 - tx) * r0[j] + tx * r0[j + 1]) + ty * ((1 - tx) * r1[j] + tx * r1[j + 1]);
  }
};

// Which rays of a scan lie within ``tolerance`` of the terrain (local_layer.dem_ground):
// the scanner at ``pos`` (map) with rotation ``R`` (row-major, into the map); rays with a
// range outside [rmin, min(rmax, max_range)] or not finite are not tested (false).
inline std::vector<char> demGround(const Heightfield& hf, const double pos[3], const double R[9],
                                   const std::vector<float>& ranges, double angle_min, double inc, double rmin,
                                   double rmax, double max_range, double tolerance, int* count = nullptr,
                                   double per_metre = 0.0, double slack = 0.0,
                                   double cap = std::numeric_limits<double>::infinity())
{
  const double e = 0.25;  // local_layer.GRADIENT_STEP
  std::vector<char> out(ranges.size(), 0);
  const double top = std::min(rmax, max_range);
  int n = 0;
  for (size_t i = 0; i < ranges.size(); ++i)
  {
    const double r = ranges[i];
    if (!std::isfinite(r) || r < rmin || r > top)
      continue;
    const double a = angle_min + inc * static_cast<double>(i);
    const double c = std::cos(a), s = std::sin(a);
    const double x = pos[0] + (R[0] * c + R[1] * s) * r;
    const double y = pos[1] + (R[3] * c + R[4] * s) * r;
    const double zz = pos[2] + (R[6] * c + R[7] * s) * r;
    double tol = tolerance + per_metre * r;
    if (slack > 0.0)
    {
      const double gx = (hf.height(x + e, y) - hf.height(x - e, y)) / (2.0 * e);
      const double gy = (hf.height(x, y + e) - hf.height(x, y - e)) / (2.0 * e);
      tol += slack * std::hypot(gx, gy);
    }
    if (std::fabs(zz - hf.height(x, y)) <= std::min(tol, cap))
    {
      out[i] = 1;
      ++n;
    }
  }
  if (count != nullptr)
    *count = n;
  return out;
}

// base_link's height on its wheels (local_layer.base_on_wheels): the mean over the wheels
// (centres in base_link, z 0) of the height at which each centre stands ``wheel_radius``
// over the terrain under it, the vehicle at (x, y) with rotation ``R`` (row-major, into the
// map); ``grad``: the norm of the mean of the terrain's gradients under the wheels.
inline double baseOnWheels(const Heightfield& hf, double x, double y, const double R[9], double wheel_radius,
                           const std::vector<Point>& wheels, double* grad)
{
  const double e = 0.25;  // local_layer.GRADIENT_STEP
  double z = 0.0, gx = 0.0, gy = 0.0;
  for (const Point& w : wheels)
  {
    const double px = x + R[0] * w.x + R[1] * w.y, py = y + R[3] * w.x + R[4] * w.y;
    z += hf.height(px, py) + wheel_radius - (R[6] * w.x + R[7] * w.y);
    gx += hf.height(px + e, py) - hf.height(px - e, py);
    gy += hf.height(px, py + e) - hf.height(px, py - e);
  }
  const double n = static_cast<double>(wheels.size());
  if (grad != nullptr)
    *grad = std::hypot(gx / n / (2.0 * e), gy / n / (2.0 * e));
  return z / n;
}

// ---------------------------------------------------------------- moving obstacles (tracks.py)
struct TrackParams
{
  double horizon = 2.0, cluster_gap = 0.3, max_extent = 6.0, max_range = 15.0, gate = 0.3, max_speed = 12.0,
         min_speed = 0.5, window = 0.8;
  int min_obs = 3;
  double min_span = 0.15, max_residual = 0.08, min_travel = 0.3, end_travel = 0.9;
  int min_points = 3;
  double shape_change = 0.25, coast = 0.5, step = 0.1;
  int max_points = 8;
  double clearance = 0.2, seen_margin = 0.15, seen_angle = 0.01;
  int seen_points = 2;
  size_t max_tracks = 200;
};

struct Prediction
{
  std::vector<Point> xy;     // the scan's base_link
  std::vector<double> speed;  // [m/s] of the track each point is from
  int moving = 0;
};

// [start, end) ranges of the points (ray order) split where neighbours are more than gap apart
inline std::vector<std::pair<size_t, size_t>> clusters(const std::vector<Point>& xy, double gap)
{
  std::vector<std::pair<size_t, size_t>> out;
  if (xy.empty())
    return out;
  size_t start = 0;
  for (size_t i = 1; i < xy.size(); ++i)
  {
    const double dx = xy[i].x - xy[i - 1].x, dy = xy[i].y - xy[i - 1].y;
    if (dx * dx + dy * dy > gap * gap)
    {
      out.emplace_back(start, i);
      start = i;
    }
  }
  out.emplace_back(start, xy.size());
  return out;
}

// A scan's rays placed in the odometric frame (tracks.SeenScan)
struct SeenScan
{
  double t, ox, oy, c, s;
  Rays rays;
};

// At most k indices of a..b-1, evenly spread, the first and the last included (tracks.picks)
inline std::vector<size_t> picks(size_t a, size_t b, long k)
{
  const long n = static_cast<long>(b - a);
  k = std::min<long>(n, k);
  std::vector<size_t> idx;
  if (k > 1)
    for (long i = 0; i < k; ++i)
      idx.push_back(a + static_cast<size_t>((i * (n - 1)) / (k - 1)));
  else
    idx.push_back(a);
  return idx;
}

// How many of the points (odometric frame) lie where ``scan`` saw through: of the rays passing
// within seen_margin of one (widened by seen_angle and a ray), none stopped short of
// seen_margin beyond it and at least half are known (tracks.seen_through)
inline int seenThrough(const SeenScan& scan, const std::vector<Point>& pts, const TrackParams& p)
{
  const Rays& r = scan.rays;
  const double det = r.m00 * r.m11 - r.m01 * r.m10;
  const long n = static_cast<long>(r.free.size());
  if (std::fabs(det) < 1e-6 || n == 0 || r.inc == 0.0)
    return 0;
  const bool full = std::fabs(r.inc) * static_cast<double>(n) >= 2.0 * M_PI - 0.5 * std::fabs(r.inc);
  int count = 0;
  for (const Point& q : pts)
  {
    const double dx = q.x - scan.ox, dy = q.y - scan.oy;
    const double bx = scan.c * dx + scan.s * dy, by = -scan.s * dx + scan.c * dy;
    const double u = (r.m11 * bx - r.m01 * by) / det, v = (-r.m10 * bx + r.m00 * by) / det;
    const double rng = std::sqrt(u * u + v * v);
    if (rng <= p.seen_margin)  // at the laser: nothing to see through
      continue;
    const double a = std::atan2(v, u);
    const double w = 1.0 + (p.seen_angle + std::asin(p.seen_margin / rng)) / std::fabs(r.inc);
    bool in = false;
    double fi = 0.0;
    for (const double cand : { a, a + 2.0 * M_PI, a - 2.0 * M_PI })
    {
      const double f = (cand - r.angle_min) / r.inc;
      if (-0.5 <= f && f <= static_cast<double>(n) - 0.5)
      {
        fi = f;
        in = true;
        break;
      }
    }
    if (!in)
      continue;
    const long lo = static_cast<long>(std::floor(fi - w)), hi = static_cast<long>(std::ceil(fi + w));
    if ((lo < 0 || hi > n - 1) && !full)
      continue;
    const double need = rng + p.seen_margin;
    bool short_of = false;
    long known = 0;
    for (long i = lo; i <= hi && !short_of; ++i)
    {
      const double f = r.free[static_cast<size_t>(((i % n) + n) % n)];
      if (std::isnan(f))  // unknown
        continue;
      if (f < need)
        short_of = true;
      else
        ++known;
    }
    if (!short_of && 2 * known >= hi - lo + 1)
      ++count;
  }
  return count;
}

class MotionTracker
{
public:
  struct Obs
  {
    double t, x, y;
    std::vector<Point> shape;  // the cluster's picked points (odometric frame)
  };
  struct Track
  {
    long ident = 0;
    std::vector<Obs> hist;  // the window's observations (the ends' history; the centroid's from since)
    double radius = 0.0, last_t = 0.0, since = -kInf, vx = 0.0, vy = 0.0;
    bool moving = false, moved = false;
  };

  explicit MotionTracker(const TrackParams& p = TrackParams()) : p_(p) {}

  void reset()
  {
    tracks_.clear();
    last_stamp = -kInf;
    prediction = Prediction();
    scans_.clear();
  }

  // A scan's points (base_link, ray order) at ``stamp`` with the odometric pose (x, y, yaw)
  // then, and its rays (null: no test of what was seen through)
  const Prediction& update(double stamp, const std::vector<Point>& xy, double ex, double ey, double eyaw,
                           const Rays* rays = nullptr)
  {
    const TrackParams& p = p_;
    if (p.horizon <= 0.0 || !(stamp > last_stamp))
      return prediction;
    last_stamp = stamp;
    const double c = std::cos(eyaw), s = std::sin(eyaw);
    if (rays == nullptr)
      scans_.clear();
    else
    {
      std::vector<SeenScan> kept;
      for (SeenScan& sc : scans_)
        if (sc.t >= stamp - p.window)
          kept.push_back(std::move(sc));
      kept.push_back(
          SeenScan{ stamp, ex + c * rays->ox - s * rays->oy, ey + s * rays->ox + c * rays->oy, c, s, *rays });
      scans_ = std::move(kept);
    }
    struct Found
    {
      double x, y, r;
      size_t a, b;
    };
    std::vector<Found> found;
    // running sums, each cluster's sum their difference (tracks.centroids)
    std::vector<double> csx(xy.size() + 1, 0.0), csy(xy.size() + 1, 0.0);
    for (size_t i = 0; i < xy.size(); ++i)
    {
      csx[i + 1] = csx[i] + xy[i].x;
      csy[i + 1] = csy[i] + xy[i].y;
    }
    for (const auto& ab : clusters(xy, p.cluster_gap))
    {
      const double n = static_cast<double>(ab.second - ab.first);
      const double bx = (csx[ab.second] - csx[ab.first]) / n, by = (csy[ab.second] - csy[ab.first]) / n;
      double r = 0.0;
      for (size_t i = ab.first; i < ab.second; ++i)
      {
        const double dx = xy[i].x - bx, dy = xy[i].y - by;
        r = std::max(r, std::sqrt(dx * dx + dy * dy));
      }
      if (static_cast<long>(ab.second - ab.first) < p.min_points || r > p.max_extent ||
          bx * bx + by * by > p.max_range * p.max_range)
        continue;
      found.push_back(Found{ ex + c * bx - s * by, ey + s * bx + c * by, r, ab.first, ab.second });
    }
    std::vector<Track> live;  // moved out of tracks_, which is rebuilt below
    for (Track& k : tracks_)
      if (stamp - k.last_t <= p.coast)
        live.push_back(std::move(k));
    struct Pair
    {
      double d;
      size_t ti, ci;
      bool operator<(const Pair& o) const
      {
        if (d != o.d)
          return d < o.d;
        if (ti != o.ti)
          return ti < o.ti;
        return ci < o.ci;
      }
    };
    std::vector<Pair> pairs;
    for (size_t ti = 0; ti < live.size(); ++ti)
    {
      const Track& k = live[ti];
      const double dt = stamp - k.last_t;
      const double px = k.hist.back().x + k.vx * dt, py = k.hist.back().y + k.vy * dt;
      const double gate = p.gate + p.max_speed * dt;
      for (size_t ci = 0; ci < found.size(); ++ci)
      {
        const double dx = found[ci].x - px, dy = found[ci].y - py;
        const double d = std::sqrt(dx * dx + dy * dy);
        if (d <= gate)
          pairs.push_back(Pair{ d, ti, ci });
      }
    }
    std::sort(pairs.begin(), pairs.end());
    std::vector<bool> used_t(live.size(), false), used_c(found.size(), false);
    std::vector<long> matched(found.size(), -1);
    for (const Pair& pr : pairs)
    {
      if (used_t[pr.ti] || used_c[pr.ci])
        continue;
      used_t[pr.ti] = used_c[pr.ci] = true;
      matched[pr.ci] = static_cast<long>(pr.ti);
    }
    std::vector<Track> next;
    for (size_t ti = 0; ti < live.size(); ++ti)
      if (!used_t[ti])
        next.push_back(std::move(live[ti]));
    Prediction out;
    for (size_t ci = 0; ci < found.size(); ++ci)
    {
      const Found& f = found[ci];
      Track k;
      if (matched[ci] >= 0)
        k = std::move(live[static_cast<size_t>(matched[ci])]);  // each track matches one cluster at most
      else
      {
        k.ident = next_id_++;
        k.radius = f.r;
        k.last_t = stamp;
      }
      if (std::fabs(f.r - k.radius) > p.shape_change)
        k.since = stamp;
      std::vector<Obs> kept;
      for (Obs& o : k.hist)
        if (o.t >= stamp - p.window)
          kept.push_back(std::move(o));
      Obs now{ stamp, f.x, f.y, {} };
      for (size_t i : picks(f.a, f.b, p.max_points))
        now.shape.push_back(Point{ ex + c * xy[i].x - s * xy[i].y, ey + s * xy[i].x + c * xy[i].y });
      kept.push_back(std::move(now));
      k.hist = std::move(kept);
      k.radius = f.r;
      k.last_t = stamp;
      size_t first = 0;
      while (k.hist[first].t < k.since)
        ++first;
      std::vector<Obs>::const_iterator from = k.hist.begin() + static_cast<long>(first);
      double vx = 0.0, vy = 0.0;
      bool ok = fit(from, k.hist.end(), vx, vy);
      double speed = ok ? std::sqrt(vx * vx + vy * vy) : 0.0;
      k.moving = ok && p.min_speed <= speed && speed <= p.max_speed &&
                 speed * (k.hist.back().t - k.hist[first].t) >= p.min_travel + f.r;
      if (k.moving && rays != nullptr)
      {
        k.moving = movedThrough(k, first);
        refused += k.moving ? 0 : 1;
      }
      if (!k.moving && rays != nullptr)
        for (const bool last : { false, true })
          if (endMoves(k, last, vx, vy))
          {
            ok = k.moving = true;
            speed = std::sqrt(vx * vx + vy * vy);
            break;
          }
      k.vx = ok ? vx : 0.0;
      k.vy = ok ? vy : 0.0;
      k.moved = k.moved || k.moving;
      if (k.moving)
      {
        ++out.moving;
        predict(xy, f.a, f.b, c * k.vx + s * k.vy, -s * k.vx + c * k.vy, speed, out);
      }
      else if (k.moved)
        predict(xy, f.a, f.b, 0.0, 0.0, 0.0, out);
      next.push_back(std::move(k));
    }
    std::stable_sort(next.begin(), next.end(), [](const Track& a, const Track& b) { return a.ident < b.ident; });
    if (next.size() > p.max_tracks)
      next.erase(next.begin(), next.end() - static_cast<long>(p.max_tracks));
    tracks_ = std::move(next);
    prediction = out;
    return prediction;
  }

  const std::vector<Track>& tracks() const { return tracks_; }
  double last_stamp = -kInf;
  long refused = 0;  // (track, scan) pairs whose centroid moved but that no scan saw move, over the tracker's life
  Prediction prediction;

private:
  // The velocity of the least-squares line through the centroids of [b, e) (tracks._fit)
  bool fit(std::vector<Obs>::const_iterator b, std::vector<Obs>::const_iterator e, double& vx, double& vy) const
  {
    const double tol = p_.max_residual;
    return fitWith(
        b, e, [](const Obs& o) { return Point{ o.x, o.y }; }, [tol](long) { return tol; }, vx, vy);
  }

  // ...through any point of the observations (an end of the cluster: its shape's first or last),
  // the i-th from b within tol(i) of the line
  template <class At, class Tol>
  bool fitWith(std::vector<Obs>::const_iterator b, std::vector<Obs>::const_iterator e, At at, Tol tol, double& vx,
               double& vy) const
  {
    const long n = static_cast<long>(e - b);
    if (n < p_.min_obs || (e - 1)->t - b->t < p_.min_span)
      return false;
    double st = 0.0, sx = 0.0, sy = 0.0;
    for (auto o = b; o != e; ++o)
    {
      const Point q = at(*o);
      st += o->t;
      sx += q.x;
      sy += q.y;
    }
    const double dn = static_cast<double>(n);
    const double mt = st / dn, mx = sx / dn, my = sy / dn;
    double stt = 0.0, stx = 0.0, sty = 0.0;
    for (auto o = b; o != e; ++o)
    {
      const Point q = at(*o);
      const double dt = o->t - mt;
      stt += dt * dt;
      stx += dt * (q.x - mx);
      sty += dt * (q.y - my);
    }
    if (stt <= 0.0)
      return false;
    const double fx = stx / stt, fy = sty / stt;
    for (auto o = b; o != e; ++o)
    {
      const Point q = at(*o);
      const double ex = q.x - (mx + fx * (o->t - mt)), ey = q.y - (my + fy * (o->t - mt));
      const double d = tol(o - b);
      if (ex * ex + ey * ey > d * d)
        return false;
    }
    vx = fx;
    vy = fy;
    return true;
  }

  // Whether the end of track k's cluster (its last return, or its first) moves, and its velocity
  // then: the longest run up to now of the window over which it lies on a line (each within
  // max_residual plus the rays' spacing at its range), at a speed within the limits, travelling
  // end_travel, the cluster seen to move over it (tracks._end_moves)
  bool endMoves(const Track& k, bool last, double& vx, double& vy) const
  {
    const auto at = [last](const Obs& o) { return last ? o.shape.back() : o.shape.front(); };
    std::vector<double> tol;
    double most = 0.0;
    for (const Obs& o : k.hist)
    {
      const SeenScan* sc = nullptr;
      for (const SeenScan& cand : scans_)
        if (cand.t == o.t)
        {
          sc = &cand;
          break;
        }
      if (sc == nullptr)
        return false;
      const Point q = at(o);
      tol.push_back(p_.max_residual + std::sqrt((q.x - sc->ox) * (q.x - sc->ox) + (q.y - sc->oy) * (q.y - sc->oy)) *
                                          std::fabs(sc->rays.inc));
      most = std::max(most, tol.back());
    }
    const Point l = at(k.hist.back());
    double reach = 0.0;
    for (const Obs& o : k.hist)
    {
      const Point q = at(o);
      reach = std::max(reach, std::sqrt((q.x - l.x) * (q.x - l.x) + (q.y - l.y) * (q.y - l.y)));
    }
    if (reach + 2.0 * most < p_.end_travel)
      return false;
    const long n = static_cast<long>(k.hist.size());
    for (long i = 0; i + p_.min_obs <= n; ++i)
    {
      double fx = 0.0, fy = 0.0;
      if (!fitWith(
              k.hist.begin() + i, k.hist.end(), at, [&tol, i](long j) { return tol[static_cast<size_t>(i + j)]; },
              fx, fy))
        continue;
      const double speed = std::sqrt(fx * fx + fy * fy);
      if (p_.min_speed <= speed && speed <= p_.max_speed &&
          speed * (k.hist.back().t - k.hist[static_cast<size_t>(i)].t) >= p_.end_travel &&
          movedThrough(k, static_cast<size_t>(i)))
      {
        vx = fx;
        vy = fy;
        return true;
      }
      return false;
    }
    return false;
  }

  // Whether the track's cluster entered space the scan of its i-th observation (the start of the
  // run that moved) saw through, or left space the current scan sees through
  // (tracks.MotionTracker._moved_through)
  bool movedThrough(const Track& k, size_t i) const
  {
    const SeenScan* first = nullptr;
    for (const SeenScan& sc : scans_)
      if (sc.t == k.hist[i].t)
      {
        first = &sc;
        break;
      }
    if (first == nullptr)
      return false;
    return seenThrough(*first, k.hist.back().shape, p_) >= p_.seen_points ||
           seenThrough(scans_.back(), k.hist[i].shape, p_) >= p_.seen_points;
  }

  void predict(const std::vector<Point>& xy, size_t a, size_t b, double ux, double uy, double speed,
               Prediction& out) const
  {
    const std::vector<size_t> idx = picks(a, b, p_.max_points);
    const long steps =
        speed > 0.0 ? std::max<long>(1, static_cast<long>(std::ceil(speed * p_.horizon / p_.step))) : 0;
    const double cl = p_.clearance;
    for (long j = 0; j <= steps; ++j)
    {
      const double tau = steps ? p_.horizon * static_cast<double>(j) / static_cast<double>(steps) : 0.0;
      for (size_t i : idx)
      {
        const double x = xy[i].x + ux * tau, y = xy[i].y + uy * tau;
        if (j > 0)
        {
          out.xy.push_back(Point{ x, y });
          out.speed.push_back(speed);
        }
        if (cl > 0.0)
        {
          const Point copies[4] = { { x + cl, y }, { x - cl, y }, { x, y + cl }, { x, y - cl } };
          for (const Point& q : copies)
          {
            out.xy.push_back(q);
            out.speed.push_back(speed);
          }
        }
      }
    }
  }

  TrackParams p_;
  std::vector<Track> tracks_;
  std::vector<SeenScan> scans_;  // the window's scans with rays, oldest first
  long next_id_ = 0;
};

// ---------------------------------------------------------------- the guard (guard.py)
struct Scanner
{
  std::string topic, frame, covers = "forward";  // covers: forward | reverse | both
  std::string no_return = "inf";                 // inf (REP 117) | zero | beyond_max: rep117Ranges
};

struct Params
{
  std::vector<Scanner> scanners;
  double padding = 0.15, step = 0.05, brake_decel = 3.5, slow_decel = 1.0, brake_latency = 0.15, margin = 0.3,
         warning_margin = 0.8, creep_speed = 0.3, creep_margin = 0.45, scan_period = 0.1, scan_timeout = 0.35,
         max_scan_age = 0.25, max_future = 0.05, state_timeout = 0.2, blind_fraction = 0.5, clear_time = 1.0,
         release_accel = 0.5, stop_speed = 0.1, stop_brake = 1.0, slope_unknown = 0.15, slope_tau = 4.0,
         slope_smoothing = 1.0, imu_timeout = 0.5, zone_sigmas = 2.0, max_position_sd = 1.0, pose_timeout = 0.3;
  TrackParams track;  // the moving-obstacle tracker's keys, track_<name> in the configuration
  std::vector<Point> zone;
};

struct Vehicle
{
  Footprint body;  // unpadded (self-returns, collisions)
  double wheelbase = 1.0, ratio = 1.0, max_rate = 1.0;
};

struct Decision
{
  int action = CLEAR;
  double limit = kInf;
  std::string reason, field;
  double free = kInf, protective = 0.0, protective_request = 0.0, warning = 0.0;
  bool has_nearest = false;
  Point nearest;
  std::string scanner;
  double scan_stamp = std::numeric_limits<double>::quiet_NaN();
  int direction = 0;
  double slope = 0.0;
};

struct Setpoint
{
  double speed = 0.0, handlebar = 0.0, brake = 0.0;
};

class Guard
{
public:
  // ``terrain``: the DEM in the map frame if known (the braking slope), or null; it must outlive the guard
  Guard(const Params& p, const Vehicle& v, const Heightfield* terrain = nullptr)
    : p_(p), v_(v), fp_(v.body.grown(p.padding)), scans_(p.scanners.size()),
      terrain_(terrain != nullptr && !terrain->empty() ? terrain : nullptr),
      trackers_(p.scanners.size(), MotionTracker(p.track))
  {
  }

  const Params& params() const { return p_; }
  int mode() const { return mode_; }
  bool hasLast() const { return has_last_; }
  const Decision& last() const { return last_; }
  bool hasState() const { return has_state_; }
  double stateStamp() const { return state_t_; }
  double stateSpeed() const { return state_v_; }
  double stateHandlebar() const { return state_h_; }
  int protective_stops = 0, fault_stops = 0, zone_stops = 0;

  // ------------------------------------------------------------ inputs
  void onState(double stamp, double speed, double handlebar)
  {
    if (!has_ego_ || !has_state_)
    {
      has_ego_ = true;
      ego_t_ = stamp;
      ego_ = { 0.0, 0.0, 0.0 };
    }
    else
    {
      const double dt = stamp - ego_t_;
      if (0.0 < dt && dt <= 1.0)
      {
        ego_ = advance(ego_, state_v_, state_h_, dt);
        ego_t_ = stamp;
      }
      else if (dt > 1.0)
      {
        ego_t_ = stamp;
        for (auto& tr : trackers_)
          tr.reset();
      }
    }
    has_state_ = true;
    state_t_ = stamp;
    state_v_ = speed;
    state_h_ = handlebar;
  }
  // the pitch, low-passed over slope_smoothing (guard.py)
  void onPitch(double stamp, double pitch)
  {
    if (has_slope_ && stamp > slope_t_ && p_.slope_smoothing > 0.0)
      pitch = slope_p_ + std::min(1.0, (stamp - slope_t_) / p_.slope_smoothing) * (pitch - slope_p_);
    else if (has_slope_ && stamp <= slope_t_)
      return;
    has_slope_ = true;
    slope_t_ = stamp;
    slope_p_ = pitch;
  }
  void onPose(double stamp, double x, double y, double yaw, double sd)
  {
    has_pose_ = true;
    pose_ = { stamp, x, y, yaw, sd };
  }
  // ``points`` null with ``error``: it came but cannot be used
  void onScan(size_t i, double stamp, const ScanPoints* points, const std::string& error = "")
  {
    ScanState& sc = scans_[i];
    sc.stamp = stamp;
    sc.error = error;
    sc.points.clear();
    if (points == nullptr)
      return;
    for (const auto& q : points->xy)
      if (!v_.body.contains(q.x, q.y))
        sc.points.push_back(q);
    sc.counts = { points->n_rays, points->n_invalid, points->n_zero, points->n_beyond };
    std::array<double, 3> e;
    if (egoAt(stamp, e))
      trackers_[i].update(stamp, sc.points, e[0], e[1], e[2], points->has_rays ? &points->rays : nullptr);
  }

  // The bicycle model (fields.sweep's) over dt [s] (guard.Guard._advance)
  std::array<double, 3> advance(const std::array<double, 3>& pose, double speed, double handlebar, double dt) const
  {
    const double w = speed * std::tan(v_.ratio * handlebar) / v_.wheelbase;
    const double mid = pose[2] + 0.5 * w * dt;
    return { pose[0] + speed * std::cos(mid) * dt, pose[1] + speed * std::sin(mid) * dt, pose[2] + w * dt };
  }
  // The odometric pose at ``stamp`` (guard.Guard.ego_at)
  bool egoAt(double stamp, std::array<double, 3>& out) const
  {
    if (!has_ego_ || !has_state_)
      return false;
    const double dt = std::min(std::max(stamp - ego_t_, -0.5), 0.5);
    out = advance(ego_, state_v_, state_h_, dt);
    return true;
  }
  const MotionTracker& tracker(size_t i) const { return trackers_[i]; }

  bool pitch(double now, double& out) const
  {
    if (!has_slope_ || now - slope_t_ > p_.imu_timeout)
      return false;
    out = slope_p_;
    return true;
  }

  // The DEM's mean downhill grade along the motion over the stopping distance (guard.py's dem_slope)
  bool demSlope(double now, int direction, double speed, double reaction, double& out) const
  {
    if (terrain_ == nullptr || !has_pose_ || now - pose_.stamp > p_.pose_timeout)
      return false;
    const double c = direction * std::cos(pose_.yaw), sn = direction * std::sin(pose_.yaw);
    double slope = 0.0;
    for (int i = 0; i < 2; ++i)
    {
      const double d =
          std::max(stoppingDistance(speed, reaction, effectiveDecel(p_.brake_decel, slope)) + p_.margin, p_.step);
      const double h0 = terrain_->height(pose_.x, pose_.y), h1 = terrain_->height(pose_.x + c * d, pose_.y + sn * d);
      slope = std::atan2(h0 - h1, d);
    }
    out = slope;
    return true;
  }

  // ------------------------------------------------------------ decide
  Decision decide(double now, double req_speed, double req_handlebar)
  {
    const Params& p = p_;
    std::string fault = faultReason(now);
    const double v_m = has_state_ ? state_v_ : 0.0;
    const double h_m = has_state_ ? state_h_ : req_handlebar;
    int direction;
    if (std::fabs(v_m) >= p.stop_speed)
      direction = v_m > 0 ? 1 : -1;
    else
      direction = req_speed == 0.0 ? 0 : (req_speed > 0 ? 1 : -1);
    if (fault.empty() && direction != 0)
      fault = scannerFault(now, direction);
    if (!fault.empty())
    {
      Decision d;
      d.action = FAULT;
      d.limit = 0.0;
      d.reason = fault;
      d.direction = direction;
      return enter(d);
    }
    const double v = std::fabs(v_m);
    double slope = 0.0;
    if (direction == 0 || !demSlope(now, direction, std::max(v, std::fabs(req_speed)), p.brake_latency + p.scan_period,
                                    slope))
    {
      double pitch_v = 0.0;
      slope = pitch(now, pitch_v) ? direction * pitch_v : p.slope_unknown;
    }
    if (direction == 0)
    {
      const bool held = mode_ == STOP || mode_ == HOLD || mode_ == FAULT;
      if (held)
      {
        mode_ = HOLD;
        clear_since_set_ = false;
      }
      Decision d;
      d.action = held ? HOLD : CLEAR;
      d.limit = held ? 0.0 : kInf;
      d.reason = held ? "holding after a stop" : "";
      d.slope = slope;
      setLast(d);
      return d;
    }
    std::vector<double> stamps;
    gatherPoints(now, stamps);
    double age = 0.0;
    if (!stamps.empty())
      age = std::max(0.0, now - *std::min_element(stamps.begin(), stamps.end()));
    const double a_brake = effectiveDecel(p.brake_decel, slope);
    const double a_slow = effectiveDecel(p.slow_decel, slope);
    const double t_prot = p.brake_latency + age;
    const double t_warn = t_prot + p.scan_period;
    const double v_req = std::fabs(req_speed);
    const double d_prot = stoppingDistance(v, t_prot, a_brake) + p.margin;
    const double d_prot_req = stoppingDistance(v_req, t_prot, a_brake) + p.margin;
    const double d_warn = stoppingDistance(std::max(v, v_req), t_warn, a_slow) + p.warning_margin;
    const Free& free = freeCached(direction, h_m, req_handlebar, std::max(v, v_req),
                                  std::max(d_warn, d_prot) + p.step, stamps);
    const double d_free = free.distance - v * age;
    const std::string who = free.index >= 0 ? owners_[static_cast<size_t>(free.index)] : "";
    const double moving = free.index >= 0 ? speeds_[static_cast<size_t>(free.index)] : 0.0;
    const std::string what =
        moving == 0.0 ? std::string("obstacle") :
                        format("moving obstacle (%.1f m/s, where it may be within %.1f s)", moving, p.track.horizon);
    double limit = allowedSpeed(d_free - p.warning_margin, t_warn, a_slow);
    if (d_free >= p.creep_margin)
      limit = std::max(limit, p.creep_speed);
    Decision d;
    d.action = CLEAR;
    d.limit = limit;
    d.free = d_free;
    d.protective = d_prot;
    d.protective_request = d_prot_req;
    d.warning = d_warn;
    d.has_nearest = free.has_point;
    d.nearest = free.point;
    d.scanner = who;
    if (!who.empty())
      d.scan_stamp = scans_[scannerIndex(who)].stamp;
    else
      d.scan_stamp = judged(now, direction);
    d.direction = direction;
    d.slope = slope;
    if (v >= p.stop_speed && d_free < d_prot)
    {
      d.action = STOP;
      d.field = "protective";
      d.reason = format("%s %.2f m along the path, inside the protective field (%.2f m at %.2f m/s)", what.c_str(),
                        std::max(d_free, 0.0), d_prot, v);
      d.limit = 0.0;
      return enter(d);
    }
    if (!p.zone.empty())
    {
      const std::string z = zoneCheck(std::max(d_prot, d_prot_req));
      if (!z.empty())
      {
        d.field = "zone";
        d.reason = z;
        d.limit = 0.0;
        if (v >= p.stop_speed)
        {
          d.action = STOP;
          return enter(d);
        }
        d.action = HOLD;
        mode_ = HOLD;
        clear_since_set_ = false;
        setLast(d);
        return d;
      }
    }
    if (d.limit < v_req)
    {
      d.field = "warning";
      d.reason = format("%s %.2f m along the path in the warning field: speed limited to %.2f m/s", what.c_str(),
                        std::max(d_free, 0.0), d.limit);
    }
    return cycle(d, now, req_speed);
  }

  Setpoint command(const Decision& d, double req_speed, double req_handlebar, double req_brake) const
  {
    if (d.action == STOP || d.action == HOLD || d.action == FAULT)
      return Setpoint{ 0.0, has_state_ ? state_h_ : req_handlebar, std::max(req_brake, p_.stop_brake) };
    const double v = std::max(-d.limit, std::min(d.limit, req_speed));
    return Setpoint{ v, req_handlebar, req_brake };
  }

private:
  struct ScanState
  {
    double stamp = -kInf;
    std::vector<Point> points;
    std::array<int, 4> counts = { 0, 0, 0, 0 };  // the last scan's rays: all, invalid, 0.0, beyond range_max
    std::string error;
  };
  struct PoseState
  {
    double stamp = 0.0, x = 0.0, y = 0.0, yaw = 0.0, sd = 0.0;
  };

  size_t scannerIndex(const std::string& topic) const
  {
    for (size_t i = 0; i < p_.scanners.size(); ++i)
      if (p_.scanners[i].topic == topic)
        return i;
    return 0;
  }

  std::string faultReason(double now) const
  {
    if (!has_state_)
      return "no vehicle state yet (vehicle/state)";
    double age = now - state_t_;
    if (age > p_.state_timeout)
      return format("vehicle state silent for %.2f s (> %s s)", age, pyfloat(p_.state_timeout).c_str());
    if (!p_.zone.empty())
    {
      if (!has_pose_)
        return "no pose yet (localization/predicted), needed for the operating zone";
      age = now - pose_.stamp;
      if (age > p_.pose_timeout)
        return format("pose silent for %.2f s (> %s s), needed for the operating zone", age, pyfloat(p_.pose_timeout).c_str());
    }
    return "";
  }

  static bool covers(const Scanner& s, int direction)
  {
    return s.covers == "both" || (s.covers == "forward") == (direction > 0);
  }

  std::string scannerFault(double now, int direction) const
  {
    bool covered = false;  // a vehicle with one laser, reversing: blind that way
    for (const Scanner& s : p_.scanners)
      covered = covered || covers(s, direction);
    if (!covered)
      return std::string("no scanner covers ") + (direction > 0 ? "forward" : "reverse") + " motion";
    for (size_t i = 0; i < p_.scanners.size(); ++i)
    {
      const Scanner& s = p_.scanners[i];
      if (!covers(s, direction))
        continue;
      const ScanState& sc = scans_[i];
      if (sc.stamp == -kInf)
        return "no scan yet from " + s.topic;
      const double age = now - sc.stamp;
      if (age > p_.scan_timeout)
        return format("%s silent for %.2f s (> %s s)", s.topic.c_str(), age, pyfloat(p_.scan_timeout).c_str());
      if (!sc.error.empty())
        return s.topic + ": " + sc.error;
      if (static_cast<double>(sc.counts[1]) / std::max(sc.counts[0], 1) > p_.blind_fraction)  // invalid / all
        return blindedReason(s.topic, sc.counts[0], sc.counts[1], sc.counts[2], sc.counts[3]);
    }
    return "";
  }

  // With nothing in the sweep, the newest fresh scan of the scanners guarding the motion (guard.Guard._judged)
  double judged(double now, int direction) const
  {
    double newest = std::numeric_limits<double>::quiet_NaN();
    for (size_t i = 0; i < p_.scanners.size(); ++i)
    {
      const ScanState& sc = scans_[i];
      if (covers(p_.scanners[i], direction) && sc.error.empty() && now - sc.stamp <= p_.scan_timeout)
        newest = std::isnan(newest) ? sc.stamp : std::max(newest, sc.stamp);
    }
    return newest;
  }

  // Every fresh scanner's points into points_ (owners_: each point's scanner)
  void gatherPoints(double now, std::vector<double>& stamps)
  {
    points_.clear();
    owners_.clear();
    speeds_.clear();
    for (size_t i = 0; i < p_.scanners.size(); ++i)
    {
      const ScanState& sc = scans_[i];
      if (!sc.error.empty() || now - sc.stamp > p_.scan_timeout)
        continue;
      points_.insert(points_.end(), sc.points.begin(), sc.points.end());
      stamps.push_back(sc.stamp);
      owners_.insert(owners_.end(), sc.points.size(), p_.scanners[i].topic);
      speeds_.insert(speeds_.end(), sc.points.size(), 0.0);
      const Prediction& pr = trackers_[i].prediction;
      if (!pr.xy.empty() && trackers_[i].last_stamp == sc.stamp)
      {
        points_.insert(points_.end(), pr.xy.begin(), pr.xy.end());
        owners_.insert(owners_.end(), pr.xy.size(), p_.scanners[i].topic);
        speeds_.insert(speeds_.end(), pr.speed.begin(), pr.speed.end());
      }
    }
  }

  static double round2(double h) { return std::nearbyint(h * 100.0) / 100.0; }

  // The sweep and its free distance, reused while the scans, the direction and (to 0.01 rad)
  // the handlebar angles stay the same (guard.Guard._free)
  const Free& freeCached(int direction, double h0, double h1, double speed, double length,
                         const std::vector<double>& stamps)
  {
    const double r0 = round2(h0), r1 = round2(h1);
    const double vq = std::ceil(speed / 0.25), lq = std::ceil(length / 0.5);
    if (cache_valid_ && cache_stamps_ == stamps && cache_dir_ == direction && cache_h0_ == r0 && cache_h1_ == r1 &&
        cache_v_ == vq && cache_l_ == lq)
      return cache_free_;
    poses_ = sweep(direction, r0, r1, v_.max_rate, 0.25 * vq, 0.5 * lq, p_.step, v_.wheelbase, v_.ratio);
    cache_free_ = freeDistance(fp_, poses_, points_, p_.step);
    cache_valid_ = true;
    cache_stamps_ = stamps;
    cache_dir_ = direction;
    cache_h0_ = r0;
    cache_h1_ = r1;
    cache_v_ = vq;
    cache_l_ = lq;
    return cache_free_;
  }

  std::string zoneCheck(double d_prot) const
  {
    const PoseState& ps = pose_;
    if (ps.sd > p_.max_position_sd)
      return format("position uncertain: sd %.2f m (> %s m) in the operating zone", ps.sd, pyfloat(p_.max_position_sd).c_str());
    const Footprint fp = fp_.grown(p_.zone_sigmas * ps.sd);
    const double c = std::cos(ps.yaw), s = std::sin(ps.yaw);
    for (size_t k = 0; k < poses_.size(); ++k)
    {
      if (static_cast<double>(k) * p_.step > d_prot + p_.step)
        continue;
      const Pose2& q = poses_[k];
      for (const Point& corner : fp.corners(ps.x + c * q.x - s * q.y, ps.y + s * q.x + c * q.y, ps.yaw + q.th))
        if (!inPolygon(corner, p_.zone))
          return "the footprint would leave the operating zone within the protective distance";
    }
    return "";
  }

  void setLast(const Decision& d)
  {
    last_ = d;
    has_last_ = true;
  }

  Decision enter(const Decision& d)
  {
    if (d.action == STOP && mode_ != STOP)
    {
      if (d.field == "zone")
        ++zone_stops;
      else
        ++protective_stops;
    }
    if (d.action == FAULT && mode_ != FAULT)
      ++fault_stops;
    if (mode_ != d.action)
    {
      stop_field_ = d.field;
      stop_reason_ = d.reason;
    }
    mode_ = d.action;
    clear_since_set_ = false;
    release_set_ = false;
    setLast(d);
    return d;
  }

  Decision cycle(Decision d, double now, double req_speed)
  {
    const double v_m = has_state_ ? std::fabs(state_v_) : 0.0;
    if (mode_ == STOP || mode_ == FAULT)
    {
      if (v_m < p_.stop_speed)
        mode_ = HOLD;
      else
      {
        d.action = mode_;
        d.limit = 0.0;
        d.field = stop_field_;
        d.reason = "braking to a stop: " + stop_reason_;
        setLast(d);
        return d;
      }
    }
    if (mode_ == HOLD)
    {
      const bool clear = d.free >= d.protective_request;
      if (clear)
      {
        if (!clear_since_set_)
        {
          clear_since_set_ = true;
          clear_since_ = now;
        }
        if (now - clear_since_ >= p_.clear_time)
        {
          mode_ = CLEAR;
          release_set_ = true;
          release_t_ = now;
        }
      }
      else
        clear_since_set_ = false;
      if (mode_ == HOLD)
      {
        d.action = HOLD;
        d.limit = 0.0;
        const double waited = clear_since_set_ ? now - clear_since_ : 0.0;
        if (clear)
          d.reason = format("holding after a stop: field clear for %.1f of %s s", waited, pyfloat(p_.clear_time).c_str());
        else if (d.reason.empty())
          d.reason = "holding after a stop: the field is not clear";
        setLast(d);
        return d;
      }
    }
    if (release_set_)
    {
      const double ramp = p_.release_accel * (now - release_t_);
      if (ramp >= std::fabs(req_speed) || ramp >= d.limit)
        release_set_ = false;
      else
      {
        d.limit = ramp;
        if (d.reason.empty())
          d.reason = "releasing after a stop";
      }
    }
    d.action = d.limit < std::fabs(req_speed) - 1e-6 ? SLOW : CLEAR;
    setLast(d);
    return d;
  }

  Params p_;
  Vehicle v_;
  Footprint fp_;
  std::vector<ScanState> scans_;
  const Heightfield* terrain_;
  bool has_state_ = false, has_slope_ = false, has_pose_ = false;
  double state_t_ = 0.0, state_v_ = 0.0, state_h_ = 0.0, slope_t_ = 0.0, slope_p_ = 0.0;
  PoseState pose_;
  int mode_ = CLEAR;
  bool clear_since_set_ = false, release_set_ = false, has_last_ = false;
  double clear_since_ = 0.0, release_t_ = 0.0;
  Decision last_;
  std::string stop_field_, stop_reason_;
  std::vector<Point> points_;
  std::vector<std::string> owners_;
  std::vector<double> speeds_;
  std::vector<MotionTracker> trackers_;
  bool has_ego_ = false;
  double ego_t_ = 0.0;
  std::array<double, 3> ego_ = { 0.0, 0.0, 0.0 };
  std::vector<Pose2> poses_;
  bool cache_valid_ = false;
  std::vector<double> cache_stamps_;
  int cache_dir_ = 0;
  double cache_h0_ = 0.0, cache_h1_ = 0.0, cache_v_ = 0.0, cache_l_ = 0.0;
  Free cache_free_;
};

// ---------------------------------------------------------------- configuration
// What quadrivio_navigation/ros/guard_config.py writes (read its docstring): the parameters
// checked by the Python configuration code, the vehicle and the scenario's terrain.
struct Config
{
  Params params;
  Vehicle vehicle;
  double wheel_radius = 0.0;
  std::vector<Point> wheels;  // centres in base_link ("tracks"; none: base_link over the DEM at its origin)
  double imu_rpy[3] = { 0.0, 0.0, 0.0 };
  double imu_xyz[3] = { 0.0, 0.0, 0.0 };
  std::string base_frame = "base_link";
  double request_timeout = 0.25, ground_tolerance = 0.15, ground_position_sigmas = 2.0, ground_tolerance_max = 0.3,
         ground_position_sd_min = 0.5;
  Heightfield terrain;
};

// The configuration's numeric keys (guard.yaml's names) and where ``c`` holds them: real numbers
// in ``fields``, whole numbers in ``counts``
inline void paramKeys(Config& c, std::map<std::string, double*>& fields, std::map<std::string, int*>& counts)
{
  fields = {
    { "padding", &c.params.padding },
    { "step", &c.params.step },
    { "brake_decel", &c.params.brake_decel },
    { "slow_decel", &c.params.slow_decel },
    { "brake_latency", &c.params.brake_latency },
    { "margin", &c.params.margin },
    { "warning_margin", &c.params.warning_margin },
    { "creep_speed", &c.params.creep_speed },
    { "creep_margin", &c.params.creep_margin },
    { "scan_period", &c.params.scan_period },
    { "scan_timeout", &c.params.scan_timeout },
    { "max_scan_age", &c.params.max_scan_age },
    { "max_future", &c.params.max_future },
    { "state_timeout", &c.params.state_timeout },
    { "blind_fraction", &c.params.blind_fraction },
    { "clear_time", &c.params.clear_time },
    { "release_accel", &c.params.release_accel },
    { "stop_speed", &c.params.stop_speed },
    { "stop_brake", &c.params.stop_brake },
    { "slope_unknown", &c.params.slope_unknown },
    { "slope_tau", &c.params.slope_tau },
    { "slope_smoothing", &c.params.slope_smoothing },
    { "imu_timeout", &c.params.imu_timeout },
    { "zone_sigmas", &c.params.zone_sigmas },
    { "max_position_sd", &c.params.max_position_sd },
    { "pose_timeout", &c.params.pose_timeout },
    { "track_horizon", &c.params.track.horizon },
    { "track_cluster_gap", &c.params.track.cluster_gap },
    { "track_max_extent", &c.params.track.max_extent },
    { "track_max_range", &c.params.track.max_range },
    { "track_gate", &c.params.track.gate },
    { "track_max_speed", &c.params.track.max_speed },
    { "track_min_speed", &c.params.track.min_speed },
    { "track_window", &c.params.track.window },
    { "track_min_span", &c.params.track.min_span },
    { "track_max_residual", &c.params.track.max_residual },
    { "track_min_travel", &c.params.track.min_travel },
    { "track_end_travel", &c.params.track.end_travel },
    { "track_shape_change", &c.params.track.shape_change },
    { "track_coast", &c.params.track.coast },
    { "track_step", &c.params.track.step },
    { "track_clearance", &c.params.track.clearance },
    { "track_seen_margin", &c.params.track.seen_margin },
    { "track_seen_angle", &c.params.track.seen_angle },
  };
  counts = {  // whole numbers: a fraction is an error
    { "track_min_obs", &c.params.track.min_obs },
    { "track_min_points", &c.params.track.min_points },
    { "track_max_points", &c.params.track.max_points },
    { "track_seen_points", &c.params.track.seen_points },
  };
}

// The node's numeric keys (``node <name> <value>`` lines, each optional) and where ``c`` holds them
inline std::map<std::string, double*> nodeKeys(Config& c)
{
  return { { "request_timeout", &c.request_timeout },
           { "ground_tolerance", &c.ground_tolerance },
           { "ground_position_sigmas", &c.ground_position_sigmas },
           { "ground_tolerance_max", &c.ground_tolerance_max },
           { "ground_position_sd_min", &c.ground_position_sd_min } };
}

// Read a configuration from ``in``; false with ``error`` naming the line that is wrong
inline bool readConfig(FILE* in, Config& c, std::string& error)
{
  std::map<std::string, double*> fields;
  std::map<std::string, int*> counts;
  paramKeys(c, fields, counts);
  std::map<std::string, double*> node = nodeKeys(c);
  std::map<std::string, bool> seen;
  char line[4096];
  bool has_body = false, has_vehicle = false;
  Point tracks_line{ 0.0, 0.0 };  // (front, rear) track [m]
  while (std::fgets(line, sizeof(line), in) != nullptr)
  {
    std::string text(line);
    while (!text.empty() && (text.back() == '\n' || text.back() == '\r'))
      text.pop_back();
    char a[256] = { 0 }, b[256] = { 0 }, d[256] = { 0 };
    double x[5];
    if (text == "end")
    {
      for (const auto& kv : fields)
        if (!seen[kv.first])
          return error = "no value for parameter '" + kv.first + "'", false;
      for (const auto& kv : counts)
        if (!seen[kv.first])
          return error = "no value for parameter '" + kv.first + "'", false;
      if (c.params.scanners.empty())
        return error = "no scanner", false;
      if (!has_body || !has_vehicle)
        return error = "no vehicle geometry (body, vehicle)", false;
      if (tracks_line.x != 0.0 || tracks_line.y != 0.0)
      {
        if (!(tracks_line.x > 0.0 && tracks_line.y > 0.0))
          return error = "tracks must be > 0 m", false;
        const double wb = c.vehicle.wheelbase, f = 0.5 * tracks_line.x, r = 0.5 * tracks_line.y;
        c.wheels = { Point{ wb, f }, Point{ wb, -f }, Point{ 0.0, r }, Point{ 0.0, -r } };
      }
      return true;
    }
    if (std::sscanf(line, "param %255s %lf", a, &x[0]) == 2)
    {
      auto it = fields.find(a);
      auto n = counts.find(a);
      if (it != fields.end())
        *it->second = x[0];
      else if (n != counts.end() && x[0] == std::floor(x[0]) && std::fabs(x[0]) < 1e9)
        *n->second = static_cast<int>(x[0]);
      else if (n != counts.end())
        return error = std::string("parameter '") + a + "' must be a whole number", false;
      else
        return error = std::string("unknown parameter '") + a + "'", false;
      seen[a] = true;
    }
    else if (std::sscanf(line, "scanner %255s %255s %255s", a, b, d) == 3)
    {
      char e[256] = "inf";
      std::sscanf(line, "scanner %*s %*s %*s %255s", e);
      std::vector<float> none;
      const std::string bad = rep117Ranges(none, 1.0, e);
      if (!bad.empty())
        return error = "scanner " + std::string(a) + ": " + bad, false;
      c.params.scanners.push_back(Scanner{ a, b, d, e });
    }
    else if (std::sscanf(line, "zone %lf %lf", &x[0], &x[1]) == 2)
      c.params.zone.push_back(Point{ x[0], x[1] });
    else if (std::sscanf(line, "body %lf %lf %lf %lf", &x[0], &x[1], &x[2], &x[3]) == 4)
    {
      c.vehicle.body = Footprint{ x[0], x[1], x[2], x[3] };
      has_body = true;
    }
    else if (std::sscanf(line, "vehicle %lf %lf %lf %lf", &x[0], &x[1], &x[2], &x[3]) == 4)
    {
      c.vehicle.wheelbase = x[0];
      c.vehicle.ratio = x[1];
      c.vehicle.max_rate = x[2];
      c.wheel_radius = x[3];
      has_vehicle = true;
    }
    else if (std::sscanf(line, "tracks %lf %lf", &x[0], &x[1]) == 2)
      tracks_line = { x[0], x[1] };
    else if (std::sscanf(line, "imu_rpy %lf %lf %lf", &x[0], &x[1], &x[2]) == 3)
      std::copy(x, x + 3, c.imu_rpy);
    else if (std::sscanf(line, "imu_xyz %lf %lf %lf", &x[0], &x[1], &x[2]) == 3)
      std::copy(x, x + 3, c.imu_xyz);
    else if (std::sscanf(line, "node base_frame %255s", a) == 1)
      c.base_frame = a;
    else if (std::sscanf(line, "node %255s %lf", a, &x[0]) == 2 && node.count(a) != 0)
      *node[a] = x[0];
    else if (std::sscanf(line, "terrain %d %d %lf %lf %lf", &c.terrain.rows, &c.terrain.cols, &x[0], &x[1], &x[2]) == 5)
    {
      Heightfield& hf = c.terrain;
      if (hf.rows < 2 || hf.cols < 2 || hf.rows > 100000 || hf.cols > 100000 || !(x[0] > 0.0))
        return error = "bad terrain grid: " + text, false;
      hf.res = x[0];
      hf.x0 = x[1];
      hf.y0 = x[2];
      hf.z.resize(static_cast<size_t>(hf.rows) * static_cast<size_t>(hf.cols));
      if (std::fread(hf.z.data(), sizeof(double), hf.z.size(), in) != hf.z.size())
        return error = "the terrain's heights end early", false;
      if (std::fgetc(in) != '\n')
        return error = "the terrain's heights are longer than its grid", false;
    }
    else
      return error = "cannot read the line '" + text + "'", false;
  }
  return error = "the configuration ends before 'end'", false;
}

}  // namespace guard
}  // namespace quadrivio_navigation
