// Lockstep for roscpp nodes: the C++ side of quadrivio_runtime.ros.lockstep (read
// its docstring for the protocol). When /lockstep/enabled and ~lockstep are true, what the
// node's subscriptions receive is queued and counted per topic and publisher, its timers do
// not run on their own, and the simulator's rounds on /lockstep/command decide what is
// handled when (on /lockstep/command<node name>): wait for the round's clock and for every message up to its watermark,
// handle exactly those (ordered by topic, publisher, arrival), run the due timers, report
// on /lockstep/report. Otherwise every call here is plain roscpp.
#pragma once

#include <ros/ros.h>
#include <ros/callback_queue.h>
#include <rosgraph_msgs/Clock.h>
#include <std_msgs/String.h>

#include <boost/property_tree/json_parser.hpp>
#include <boost/property_tree/ptree.hpp>

#include <algorithm>
#include <chrono>

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace quadrivio_runtime
{
class Lockstep
{
public:
  explicit Lockstep(ros::NodeHandle& nh) : nh_(nh)
  {
    bool on = false, mine = false;
    ros::param::get("/lockstep/enabled", on);
    ros::param::get("~lockstep", mine);
    enabled_ = on && mine;
    if (!enabled_) return;
    name_ = ros::this_node::getName();
    report_ = nh_.advertise<std_msgs::String>("/lockstep/report", 100);
    clock_sub_ = nh_.subscribe("/clock", 10, &Lockstep::onClock, this, ros::TransportHints().tcpNoDelay());
    // Rounds block until their messages arrive: they run on a queue and thread of their own.
    ros::SubscribeOptions so = ros::SubscribeOptions::create<std_msgs::String>(
        "/lockstep/command" + name_, 100,
        boost::function<void(const std_msgs::String::ConstPtr&)>(
            [this](const std_msgs::String::ConstPtr& m) { onCommand(m); }),
        ros::VoidPtr(), &command_queue_);
    so.transport_hints = ros::TransportHints().tcpNoDelay();
    command_sub_ = nh_.subscribe(so);
    spinner_.reset(new ros::AsyncSpinner(1, &command_queue_));
    spinner_->start();
    hello_ = nh_.createWallTimer(ros::WallDuration(0.2), [this](const ros::WallTimerEvent&) {
      if (!armed_) report(-1, "");
    });
    ROS_INFO("lockstep: this node handles its inputs and timers in the simulator's rounds");
  }

  bool enabled() const { return enabled_; }

  // nh.subscribe(topic, queue, fn, obj), held back in lockstep.
  template <class M, class T>
  ros::Subscriber subscribe(const std::string& topic, uint32_t queue, void (T::*fn)(const boost::shared_ptr<M const>&),
                            T* obj)
  {
    if (!enabled_) return nh_.subscribe(topic, queue, fn, obj);
    const std::string resolved = nh_.resolveName(topic);
    boost::function<void(const ros::MessageEvent<M const>&)> cb = [this, resolved, fn, obj](
                                                                        const ros::MessageEvent<M const>& ev) {
      boost::shared_ptr<M const> msg = ev.getConstMessage();
      std::lock_guard<std::mutex> lock(mutex_);
      const Key key(resolved, ev.getPublisherName());
      queue_[key].push_back([obj, fn, msg]() { (obj->*fn)(msg); });
      ++recv_[key];
      cv_.notify_all();
    };
    ros::Subscriber s = nh_.subscribe<M>(topic, 1000, cb);
    subs_.push_back(std::make_pair(resolved, s));
    return s;
  }

  template <class M>
  ros::Publisher advertise(const std::string& topic, uint32_t queue)
  {
    ros::Publisher p = nh_.advertise<M>(topic, queue);
    if (enabled_) pubs_.push_back(p);
    return p;
  }

  template <class M>
  void publish(const ros::Publisher& p, const M& m)
  {
    if (enabled_)
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++sent_[p.getTopic()];
    }
    p.publish(m);
  }

  // nh.createTimer(period, fn); in lockstep run by the rounds at the multiples of the period.
  void addTimer(double period, std::function<void()> fn)
  {
    if (!enabled_)
    {
      timers_keep_.push_back(nh_.createTimer(ros::Duration(period), [fn](const ros::TimerEvent&) { fn(); }));
      return;
    }
    Timer t;
    t.period = static_cast<int64_t>(period * 1e9 + 0.5);
    t.next = (ros::Time::now().toNSec() / t.period + 1) * t.period;
    t.fn = fn;
    std::lock_guard<std::mutex> lock(mutex_);
    timers_.push_back(t);
  }

private:
  using Key = std::pair<std::string, std::string>;
  struct Timer
  {
    int64_t period = 1, next = 0;
    std::function<void()> fn;
  };

  void onClock(const rosgraph_msgs::Clock::ConstPtr&)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    cv_.notify_all();
  }

  static std::string quote(const std::string& s)
  {
    std::string out = "\"";
    for (char c : s)
    {
      if (c == '"' || c == '\\') out += '\\';
      out += c;
    }
    return out + "\"";
  }

  void report(long seq, const std::string& error)
  {
    std::ostringstream o;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      o << "{\"node\":" << quote(name_) << ",\"seq\":" << seq << ",\"clock\":" << ros::Time::now().toNSec()
        << ",\"armed\":" << (armed_ ? "true" : "false") << ",\"sent\":{";
      bool first = true;
      if (armed_)
        for (const auto& kv : sent_)
        {
          o << (first ? "" : ",") << quote(kv.first) << ":" << kv.second - base_sent_[kv.first];
          first = false;
        }
      o << "}";
      if (!armed_ || seq < 0)  // the graph, until armed (the simulator waits for its connections)
      {
        o << ",\"subs\":{";
        first = true;
        for (const auto& s : subs_)
        {
          o << (first ? "" : ",") << quote(s.first) << ":" << s.second.getNumPublishers();
          first = false;
        }
        o << "},\"pubs\":{";
        first = true;
        for (const auto& p : pubs_)
        {
          o << (first ? "" : ",") << quote(p.getTopic()) << ":" << p.getNumSubscribers();
          first = false;
        }
        o << "}";
      }
      o << ",\"next_timer\":";
      if (timers_.empty())
        o << "null";
      else
      {
        int64_t next = timers_.front().next;
        for (const auto& t : timers_) next = std::min(next, t.next);
        o << next;
      }
      o << ",\"error\":" << quote(error) << "}";
    }
    std_msgs::String m;
    m.data = o.str();
    report_.publish(m);
  }

  void arm()
  {
    std::vector<std::function<void()>> pending;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (armed_) return;
      for (auto& kv : queue_)
        while (!kv.second.empty())
        {
          pending.push_back(kv.second.front());
          kv.second.pop_front();
        }
      base_recv_ = recv_;
      base_sent_ = sent_;
      armed_ = true;
    }
    for (auto& f : pending) f();
  }

  void onCommand(const std_msgs::String::ConstPtr& msg)
  {
    boost::property_tree::ptree cmd;
    try
    {
      std::istringstream in(msg->data);
      boost::property_tree::read_json(in, cmd);
    }
    catch (const std::exception& e)
    {
      ROS_ERROR_THROTTLE(5.0, "lockstep: malformed command: %s", e.what());
      return;
    }
    const long seq = cmd.get<long>("seq", 0);
    if (cmd.get<std::string>("arm", "") == "true")
    {
      report(-1, "");
      arm();
      report(seq, "");
      return;
    }
    std::map<Key, long> wm;
    std::map<std::string, bool> wm_topics;
    if (auto w = cmd.get_child_optional("wm"))
      for (const auto& t : *w)
        for (const auto& p : t.second)
        {
          wm[Key(t.first, p.first)] = p.second.get_value<long>();
          wm_topics[t.first] = true;
        }
    std::string error;
    try
    {
      error = round(cmd.get<int64_t>("t", 0), wm, cmd.get<std::string>("timers", "false") == "true");
    }
    catch (const std::exception& e)
    {
      error = e.what();
    }
    if (!error.empty()) ROS_ERROR_THROTTLE(5.0, "lockstep round: %s", error.c_str());
    report(seq, error);
  }

  std::string round(int64_t t_ns, const std::map<Key, long>& wm, bool run_timers)
  {
    std::vector<std::function<void()>> batch;
    std::vector<std::function<void()>> due;
    std::string error;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      if (t_ns < last_t_)
        for (auto& t : timers_) t.next = (t_ns / t.period + 1) * t.period;
      last_t_ = t_ns;
      const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
      while (true)
      {
        std::string owed;
        for (const auto& s : subs_)
          for (const auto& kv : wm)
            if (kv.first.first == s.first)
            {
              const long got = recv_[kv.first] - base_recv_[kv.first];
              if (got < kv.second) owed += " " + kv.first.first + " from " + kv.first.second;
            }
        const bool late_clock = static_cast<int64_t>(ros::Time::now().toNSec()) < t_ns;
        if (owed.empty() && !late_clock) break;
        if (std::chrono::steady_clock::now() > deadline)
        {
          // lost: go on without, counted as received and handled (never waited for again)
          error = "waited 10 s for" + owed + (late_clock ? " the clock" : "") +
                  "; going on without (this run will not repeat exactly)";
          for (const auto& s : subs_)
            for (const auto& kv : wm)
              if (kv.first.first == s.first)
              {
                const long missing = kv.second - (recv_[kv.first] - base_recv_[kv.first]);
                if (missing > 0)
                {
                  base_recv_[kv.first] -= missing;
                  delivered_[kv.first] += missing;
                }
              }
          break;
        }
        cv_.wait_for(lock, std::chrono::milliseconds(1));
      }
      for (auto& kv : queue_)
      {
        auto it = wm.find(kv.first);
        long n = it == wm.end() ? static_cast<long>(kv.second.size()) : it->second - delivered_[kv.first];
        while (n-- > 0 && !kv.second.empty())
        {
          batch.push_back(kv.second.front());
          kv.second.pop_front();
          ++delivered_[kv.first];
        }
      }
      if (run_timers)
        for (auto& t : timers_)
          if (t.next <= t_ns)
          {
            t.next = (t_ns / t.period + 1) * t.period;
            due.push_back(t.fn);
          }
    }
    for (auto& f : batch) f();
    for (auto& f : due) f();
    return error;
  }

  ros::NodeHandle nh_;
  bool enabled_ = false, armed_ = false;
  std::string name_;
  ros::Publisher report_;
  ros::Subscriber clock_sub_, command_sub_;
  ros::CallbackQueue command_queue_;
  std::unique_ptr<ros::AsyncSpinner> spinner_;
  ros::WallTimer hello_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::map<Key, std::deque<std::function<void()>>> queue_;
  std::map<Key, long> recv_, base_recv_, delivered_;
  std::map<std::string, long> sent_, base_sent_;
  std::vector<std::pair<std::string, ros::Subscriber>> subs_;
  std::vector<ros::Publisher> pubs_;
  std::vector<Timer> timers_;
  std::vector<ros::Timer> timers_keep_;
  int64_t last_t_ = 0;
};
}  // namespace quadrivio_runtime
