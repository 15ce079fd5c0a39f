// predictor_replay: the predictor's C++ core (predictor.h) driven by lines on stdin, for
// test_predictor_port.py, which drives the Python port (quadrivio_localization.predictor)
// with the same lines and compares every answer.
//
//   G wheelbase ratio max_delta      a new core
//   C speed_scale handlebar_offset steering_gain
//   E t x y theta                    an estimate
//   R t speed handlebar              a reading (prints "R 0|1": refused or taken)
//   P target                         prints "P x y theta travelled"
//   L                                prints "L speed yaw_rate" or "L none"
#include <quadrivio_localization/predictor.h>

#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>

namespace ql = quadrivio_localization;

// The next number of the line (strtod: "nan" and "inf" too, which operator>> refuses)
static double num(std::istringstream& in)
{
  std::string tok;
  in >> tok;
  return std::strtod(tok.c_str(), nullptr);
}

int main()
{
  std::unique_ptr<ql::Predictor> core;
  std::string line;
  while (std::getline(std::cin, line))
  {
    std::istringstream in(line);
    char op = 0;
    in >> op;
    if (op == 'G')
    {
      const double L = num(in), ratio = num(in), max_delta = num(in);
      core.reset(new ql::Predictor(L, ratio, max_delta));
    }
    else if (op == 'C')
    {
      ql::ModelCalibration c;
      c.speed_scale = num(in);
      c.handlebar_offset = num(in);
      c.steering_gain = num(in);
      core->setCalibration(c);
    }
    else if (op == 'E')
    {
      const double t = num(in);
      ql::Pose2 p;
      p.x = num(in);
      p.y = num(in);
      p.theta = num(in);
      core->setEstimate(t, p);
    }
    else if (op == 'R')
    {
      ql::Reading r;
      r.t = num(in);
      r.speed = num(in);
      r.handlebar = num(in);
      std::printf("R %d\n", core->addReading(r) ? 1 : 0);
    }
    else if (op == 'P')
    {
      const double target = num(in);
      double travelled = 0.0;
      const ql::Pose2 p = core->predict(target, &travelled);
      std::printf("P %.17g %.17g %.17g %.17g\n", p.x, p.y, p.theta, travelled);
    }
    else if (op == 'L')
    {
      double v, w;
      if (core->latest(v, w))
        std::printf("L %.17g %.17g\n", v, w);
      else
        std::printf("L none\n");
    }
  }
  return 0;
}
