// guard_replay: the C++ guard core driven by a script on stdin, for the cross-test against
// the Python core (test/test_guard_native.py). First the configuration
// (quadrivio_navigation/ros/guard_config.py's format, up to "end"), then one event per line:
//   state T V H | pitch T P | pose T X Y YAW SD | scanerr I T REASON...
//   scan I T N_RAYS N_INVALID N X1 Y1 ... XN YN   (points in base_link)
//   ranges I T ANGLE_MIN INC RMIN RMAX MX MY MYAW MAX_RANGE N R1..RN   (a scan through rep117Ranges (the
//                                          scanner's no_return) and scanPoints, rays included; ranges as
//                                          float32, inf and nan spelled so)
//   decide NOW SPEED HANDLEBAR BRAKE   -> "decision ACTION LIMIT FREE PROT PROT_REQ WARN HAS_NEAREST NX NY
//                                          SCAN_STAMP DIRECTION SLOPE SP_SPEED SP_HANDLEBAR SP_BRAKE STOPS FAULTS
//                                          ZONE_STOPS|FIELD|SCANNER|REASON"
//   attitude_speed T V | attitude_imu T FX FY FZ WX WY WZ -> "attitude ROLL PITCH"
//   seen OX OY C S M00 M01 M10 M11 ANGLE_MIN INC MARGIN ANGLE N F1..FN K X1 Y1..XK YK -> "seen COUNT"
//   ground X Y Z ROLL PITCH YAW ANGLE_MIN INC RMIN RMAX MAX_RANGE TOL PER_M SLACK CAP N R1..RN -> "ground 0 1 ..."
#include <quadrivio_navigation/guard_core.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace g = quadrivio_navigation::guard;

int main()
{
  g::Config config;
  std::string error;
  if (!g::readConfig(stdin, config, error))
  {
    std::fprintf(stderr, "guard_replay: bad configuration: %s\n", error.c_str());
    return 1;
  }
  g::Guard guard(config.params, config.vehicle, &config.terrain);
  g::Attitude attitude(config.params.slope_tau, 8.0, 0.25, 0.05, config.imu_xyz);
  std::string line;
  while (std::getline(std::cin, line))
  {
    std::istringstream in(line);
    std::string kind;
    in >> kind;
    if (kind == "state")
    {
      double t, v, h;
      in >> t >> v >> h;
      guard.onState(t, v, h);
    }
    else if (kind == "pitch")
    {
      double t, p;
      in >> t >> p;
      guard.onPitch(t, p);
    }
    else if (kind == "pose")
    {
      double t, x, y, yaw, sd;
      in >> t >> x >> y >> yaw >> sd;
      guard.onPose(t, x, y, yaw, sd);
    }
    else if (kind == "scan")
    {
      size_t i, n;
      double t;
      g::ScanPoints sp;
      in >> i >> t >> sp.n_rays >> sp.n_invalid >> n;
      sp.xy.resize(n);
      for (auto& p : sp.xy)
        in >> p.x >> p.y;
      guard.onScan(i, t, &sp);
    }
    else if (kind == "ranges")
    {
      size_t i, n;
      double t, amin, inc, rmin, rmax, mx, my, myaw, max_range;
      in >> i >> t >> amin >> inc >> rmin >> rmax >> mx >> my >> myaw >> max_range >> n;
      std::vector<float> ranges(n);
      for (auto& r : ranges)
      {
        std::string word;
        in >> word;
        r = std::strtof(word.c_str(), nullptr);
      }
      g::rep117Ranges(ranges, rmax, config.params.scanners.at(i).no_return);
      const g::ScanPoints sp = g::scanPoints(ranges, amin, inc, rmin, rmax, mx, my, myaw, max_range, nullptr);
      guard.onScan(i, t, &sp);
    }
    else if (kind == "seen")
    {
      g::SeenScan sc{};
      g::TrackParams tp;
      size_t n, k;
      in >> sc.ox >> sc.oy >> sc.c >> sc.s >> sc.rays.m00 >> sc.rays.m01 >> sc.rays.m10 >> sc.rays.m11 >>
          sc.rays.angle_min >> sc.rays.inc >> tp.seen_margin >> tp.seen_angle >> n;
      sc.rays.free.resize(n);
      for (auto& f : sc.rays.free)
      {
        std::string word;
        in >> word;
        f = std::strtod(word.c_str(), nullptr);  // "nan": an unknown ray
      }
      in >> k;
      std::vector<g::Point> pts(k);
      for (auto& q : pts)
        in >> q.x >> q.y;
      std::printf("seen %d\n", g::seenThrough(sc, pts, tp));
    }
    else if (kind == "scanerr")
    {
      size_t i;
      double t;
      in >> i >> t;
      std::string reason;
      std::getline(in, reason);
      guard.onScan(i, t, nullptr, reason.empty() ? reason : reason.substr(1));
    }
    else if (kind == "decide")
    {
      double now, speed, handlebar, brake;
      in >> now >> speed >> handlebar >> brake;
      const g::Decision d = guard.decide(now, speed, handlebar);
      const g::Setpoint sp = guard.command(d, speed, handlebar, brake);
      std::printf("decision %d %.17g %.17g %.17g %.17g %.17g %d %.17g %.17g %.17g %d %.17g %.17g %.17g %.17g %d %d "
                  "%d|%s|%s|%s\n",
                  d.action, d.limit, d.free, d.protective, d.protective_request, d.warning, d.has_nearest ? 1 : 0,
                  d.nearest.x, d.nearest.y, d.scan_stamp, d.direction, d.slope, sp.speed, sp.handlebar, sp.brake,
                  guard.protective_stops, guard.fault_stops, guard.zone_stops, d.field.c_str(), d.scanner.c_str(),
                  d.reason.c_str());
    }
    else if (kind == "attitude_speed")
    {
      double t, v;
      in >> t >> v;
      attitude.addSpeed(t, v);
    }
    else if (kind == "attitude_imu")
    {
      double t, f[3], w[3];
      in >> t >> f[0] >> f[1] >> f[2] >> w[0] >> w[1] >> w[2];
      attitude.addImu(t, f, w);
      std::printf("attitude %.17g %.17g\n", attitude.roll, attitude.pitch);
    }
    else if (kind == "base")
    {
      double x, y, rpy[3], R[9], grad = 0.0;
      in >> x >> y >> rpy[0] >> rpy[1] >> rpy[2];
      g::rpyMatrix(rpy[0], rpy[1], rpy[2], R);
      const double z = g::baseOnWheels(config.terrain, x, y, R, config.wheel_radius, config.wheels, &grad);
      std::printf("base %.17g %.17g\n", z, grad);
    }
    else if (kind == "ground")
    {
      double pos[3], rpy[3], amin, inc, rmin, rmax, max_range, tol, per_m, slack, cap, R[9];
      size_t n;
      in >> pos[0] >> pos[1] >> pos[2] >> rpy[0] >> rpy[1] >> rpy[2] >> amin >> inc >> rmin >> rmax >> max_range >>
          tol >> per_m >> slack;
      std::string cap_word;  // "inf" as Python prints it
      in >> cap_word >> n;
      cap = std::strtod(cap_word.c_str(), nullptr);
      std::vector<float> ranges(n);
      for (auto& r : ranges)
      {
        std::string word;  // "inf", "-inf" and "nan" as Python prints them
        in >> word;
        r = std::strtof(word.c_str(), nullptr);
      }
      g::rpyMatrix(rpy[0], rpy[1], rpy[2], R);
      const auto ground =
          g::demGround(config.terrain, pos, R, ranges, amin, inc, rmin, rmax, max_range, tol, nullptr, per_m, slack, cap);
      std::printf("ground");
      for (char c : ground)
        std::printf(" %d", c ? 1 : 0);
      std::printf("\n");
    }
    else if (!kind.empty())
    {
      std::fprintf(stderr, "guard_replay: unknown event '%s'\n", kind.c_str());
      return 2;
    }
    std::fflush(stdout);
  }
  return 0;
}
