// The obstacle guard's inputs and nothing else: a roscpp node that subscribes to what guard_cpp
// subscribes to (the same topics, types and queues) and does nothing with it. Its CPU is the
// floor under the guard's: what roscpp and the kernel cost to deliver those messages to any
// node (bench/bench_obstacles.py runs it beside the guard in the same run: guard_cpu_floor_frac).
//
//   rosrun quadrivio_navigation guard_inputs_sink [scan topic ...]   (default: scan/front scan/rear)
//
// On shutdown it logs how many messages of each topic it received.
#include <nav_msgs/Odometry.h>
#include <quadrivio_plc/Setpoint.h>
#include <quadrivio_plc/VehicleState.h>
#include <ros/ros.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2_msgs/TFMessage.h>

#include <map>
#include <string>
#include <vector>

namespace
{
std::map<std::string, long> counts;

template <class M>
ros::Subscriber sink(ros::NodeHandle& nh, const std::string& topic, uint32_t queue)
{
  long* n = &counts[topic];
  return nh.subscribe<M>(topic, queue, [n](const boost::shared_ptr<M const>&) { ++*n; });
}
}  // namespace

int main(int argc, char** argv)
{
  ros::init(argc, argv, "guard_inputs_sink");
  std::vector<std::string> scans;
  for (int i = 1; i < argc; ++i)
    scans.emplace_back(argv[i]);
  if (scans.empty())
    scans = { "scan/front", "scan/rear" };
  ros::NodeHandle nh;
  std::vector<ros::Subscriber> subs = {
    sink<quadrivio_plc::Setpoint>(nh, "vehicle/setpoint/request", 10),
    sink<quadrivio_plc::VehicleState>(nh, "vehicle/state", 10),
    sink<sensor_msgs::Imu>(nh, "imu/data", 20),
    sink<tf2_msgs::TFMessage>(nh, "/tf_static", 10),
    sink<nav_msgs::Odometry>(nh, "localization/predicted", 5),
  };
  for (const auto& s : scans)
    subs.push_back(sink<sensor_msgs::LaserScan>(nh, s, 2));
  ros::spin();
  std::string text;
  for (const auto& kv : counts)
    text += (text.empty() ? "" : ", ") + kv.first + " " + std::to_string(kv.second);
  std::printf("guard_inputs_sink received: %s\n", text.c_str());
  return 0;
}
