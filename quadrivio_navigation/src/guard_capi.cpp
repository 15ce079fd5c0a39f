// The guard's core (guard_core.h) behind a C interface, for Python through ctypes
// (quadrivio_navigation/guard_native.py): the closed loop in one process drives the guard the
// roscpp node runs, at its cost, instead of the Python reference.
#include <quadrivio_navigation/guard_core.h>

#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <string>

namespace g = quadrivio_navigation::guard;

namespace
{
struct Handle
{
  g::Config config;
  std::unique_ptr<g::Guard> guard;
};

void copyText(const std::string& text, char* out, size_t size)
{
  if (out == nullptr || size == 0)
    return;
  std::snprintf(out, size, "%s", text.c_str());
}
}  // namespace

extern "C" {

// A guard from a configuration in guard_config.py's format (``size`` bytes at ``text``); null
// with ``error`` filled when it does not read
void* qv_guard_create(const char* text, size_t size, char* error, size_t error_size)
{
  FILE* in = fmemopen(const_cast<char*>(text), size, "rb");
  if (in == nullptr)
  {
    copyText("cannot read the configuration from memory", error, error_size);
    return nullptr;
  }
  auto h = std::make_unique<Handle>();
  std::string why;
  const bool ok = g::readConfig(in, h->config, why);
  std::fclose(in);
  if (!ok)
  {
    copyText(why, error, error_size);
    return nullptr;
  }
  h->guard = std::make_unique<g::Guard>(h->config.params, h->config.vehicle, &h->config.terrain);
  return h.release();
}

// The C++ defaults of the configuration's keys, a "name value" line each (the numeric
// parameters, then the node's as "node_<name>"), for the test that holds them to guard.yaml and
// the Python parameters; the bytes written, or the bytes needed when ``size`` is too small
size_t qv_guard_defaults(char* out, size_t size)
{
  g::Config c;
  std::map<std::string, double*> fields;
  std::map<std::string, int*> counts;
  g::paramKeys(c, fields, counts);
  std::string text;
  char line[128];
  for (const auto& kv : fields)
  {
    std::snprintf(line, sizeof(line), "%s %.17g\n", kv.first.c_str(), *kv.second);
    text += line;
  }
  for (const auto& kv : counts)
  {
    std::snprintf(line, sizeof(line), "%s %d\n", kv.first.c_str(), *kv.second);
    text += line;
  }
  for (const auto& kv : g::nodeKeys(c))
  {
    std::snprintf(line, sizeof(line), "node_%s %.17g\n", kv.first.c_str(), *kv.second);
    text += line;
  }
  if (out != nullptr && size > text.size())
    std::memcpy(out, text.c_str(), text.size() + 1);
  return text.size() + 1;
}

void qv_guard_destroy(void* handle)
{
  delete static_cast<Handle*>(handle);
}

void qv_guard_on_state(void* handle, double stamp, double speed, double handlebar)
{
  static_cast<Handle*>(handle)->guard->onState(stamp, speed, handlebar);
}

void qv_guard_on_pitch(void* handle, double stamp, double pitch)
{
  static_cast<Handle*>(handle)->guard->onPitch(stamp, pitch);
}

void qv_guard_on_pose(void* handle, double stamp, double x, double y, double yaw, double sd)
{
  static_cast<Handle*>(handle)->guard->onPose(stamp, x, y, yaw, sd);
}

// Scanner ``index`` (the configuration's order): ``n`` points (x, y interleaved, base_link) of
// a scan of ``n_rays`` rays, ``n_invalid`` of them invalid (``n_zero`` of those 0.0, ``n_beyond``
// beyond range_max), and, with ``geometry`` not null,
// its rays (fields.Rays: ox, oy, m00, m01, m10, m11, angle_min, increment; ``free``: n_rays
// values); or, with ``error`` not null, a scan that came but cannot be used, and why
void qv_guard_on_scan(void* handle, size_t index, double stamp, const double* xy, size_t n, int n_rays, int n_invalid,
                      int n_zero, int n_beyond, const double* geometry, const double* free, const char* error)
{
  g::Guard& guard = *static_cast<Handle*>(handle)->guard;
  if (error != nullptr)
  {
    guard.onScan(index, stamp, nullptr, error);
    return;
  }
  g::ScanPoints sp;
  sp.n_rays = n_rays;
  sp.n_invalid = n_invalid;
  sp.n_zero = n_zero;
  sp.n_beyond = n_beyond;
  sp.xy.resize(n);
  for (size_t i = 0; i < n; ++i)
    sp.xy[i] = g::Point{ xy[2 * i], xy[2 * i + 1] };
  if (geometry != nullptr && free != nullptr)
  {
    g::Rays& r = sp.rays;
    sp.has_rays = true;
    r.ox = geometry[0];
    r.oy = geometry[1];
    r.m00 = geometry[2];
    r.m01 = geometry[3];
    r.m10 = geometry[4];
    r.m11 = geometry[5];
    r.angle_min = geometry[6];
    r.inc = geometry[7];
    r.free.assign(free, free + std::max(n_rays, 0));
  }
  guard.onScan(index, stamp, &sp);
}

// The decision on a request. ``numbers``: action, limit, free, protective, protective_request,
// warning, has_nearest, nearest x, nearest y, scan_stamp, direction, slope, protective_stops,
// fault_stops, zone_stops (15); ``texts``: reason, field and scanner, each ended by a NUL
void qv_guard_decide(void* handle, double now, double req_speed, double req_handlebar, double* numbers, char* texts,
                     size_t texts_size)
{
  g::Guard& guard = *static_cast<Handle*>(handle)->guard;
  const g::Decision d = guard.decide(now, req_speed, req_handlebar);
  const double out[] = { double(d.action),
                         d.limit,
                         d.free,
                         d.protective,
                         d.protective_request,
                         d.warning,
                         d.has_nearest ? 1.0 : 0.0,
                         d.nearest.x,
                         d.nearest.y,
                         d.scan_stamp,
                         double(d.direction),
                         d.slope,
                         double(guard.protective_stops),
                         double(guard.fault_stops),
                         double(guard.zone_stops) };
  std::memcpy(numbers, out, sizeof(out));
  std::string joined = d.reason;
  joined.push_back('\0');
  joined += d.field;
  joined.push_back('\0');
  joined += d.scanner;
  joined.push_back('\0');
  if (texts_size > 0)
  {
    const size_t n = std::min(joined.size(), texts_size);
    std::memcpy(texts, joined.data(), n);
    texts[texts_size - 1] = '\0';
  }
}

// The setpoint for a decision's action and limit (Guard::command)
void qv_guard_command(void* handle, int action, double limit, double req_speed, double req_handlebar,
                      double req_brake, double* setpoint)
{
  g::Decision d;
  d.action = action;
  d.limit = limit;
  const g::Setpoint sp = static_cast<Handle*>(handle)->guard->command(d, req_speed, req_handlebar, req_brake);
  setpoint[0] = sp.speed;
  setpoint[1] = sp.handlebar;
  setpoint[2] = sp.brake;
}

// The latest vehicle state: 1 with (stamp, speed, handlebar) in ``state``, 0 without one
int qv_guard_state(void* handle, double* state)
{
  const g::Guard& guard = *static_cast<Handle*>(handle)->guard;
  if (!guard.hasState())
    return 0;
  state[0] = guard.stateStamp();
  state[1] = guard.stateSpeed();
  state[2] = guard.stateHandlebar();
  return 1;
}

}  // extern "C"
