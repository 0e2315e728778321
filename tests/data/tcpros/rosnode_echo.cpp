// A tiny roscpp node for mrosd's interop tests and benchmark (compiled at test time, never shipped).
//   echo <string|image|cloud>         republish every /ping message on /pong
//   echo mros                         mROS paper section 5.4: answer each 1-byte /ping String "c" with a String of
//                                     2^(c - 'A') bytes on /pong (the sender picks the size, the echo node sends it)
//   ping <string|image> <sizes> <n>   for each comma-separated size, send n messages on /ping, wait for each on /pong,
//                                     print "RTT <size> <ns> <ns> ..." (one round trip per message)
//   burst <string|image> <sizes> <n>  for each size, send n messages back to back, count replies on /pong,
//                                     print "BURST <size> <received> <seconds>"; then the same burst again
//                                     on the warm connection: "WARM <size> <received> <seconds>"
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/String.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

static long long now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

static void fill(std_msgs::String& m, size_t size) { m.data.assign(size, 'x'); }
static void fill(sensor_msgs::PointCloud2& m, size_t size) {
  m.height = 1;
  m.width = size / 16;
  m.fields.resize(4);
  const char* names[] = {"x", "y", "z", "intensity"};
  for (int i = 0; i < 4; ++i) {
    m.fields[i].name = names[i];
    m.fields[i].offset = 4 * i;
    m.fields[i].datatype = sensor_msgs::PointField::FLOAT32;
    m.fields[i].count = 1;
  }
  m.point_step = 16;
  m.row_step = 16 * m.width;
  m.is_dense = true;
  m.data.assign(size, 7);
}
static void fill(sensor_msgs::Image& m, size_t size) {
  m.encoding = "mono8";
  m.height = 1;
  m.width = size;
  m.step = size;
  m.data.assign(size, 7);
}

template <class M>
struct Node;

template <class M>
static void sized_reply(Node<M>& node, const M& ping);

template <class M>
struct Node {
  ros::NodeHandle nh;
  ros::Publisher pub;
  ros::Subscriber sub;
  long long received = 0;
  long long last_ns = 0;
  bool echo = false;
  bool mros = false;  // answer with a sized reply instead of the message itself (std_msgs::String only)
  void cb(const boost::shared_ptr<M const>& m) {
    if (echo && mros) {
      reply(*m);
    } else if (echo) {
      pub.publish(*m);
    } else {
      ++received;
      last_ns = now_ns();
    }
  }
  void reply(const M& ping) { sized_reply(*this, ping); }
  Node(bool echo_, const char* in, const char* out) : echo(echo_) {
    pub = nh.advertise<M>(out, 1000);
    sub = nh.subscribe(in, 1000, &Node::cb, this, ros::TransportHints().tcpNoDelay());
  }
  void wait_connected() {
    while (ros::ok() && (pub.getNumSubscribers() == 0 || sub.getNumPublishers() == 0)) {
      ros::getGlobalCallbackQueue()->callAvailable(ros::WallDuration(0.01));
    }
  }
  bool wait_for(long long count, double timeout_s) {
    long long deadline = now_ns() + (long long)(timeout_s * 1e9);
    while (ros::ok() && received < count && now_ns() < deadline) {
      ros::getGlobalCallbackQueue()->callAvailable(ros::WallDuration(0.001));
    }
    return received >= count;
  }
};

template <class M>
static void sized_reply(Node<M>& node, const M& ping) {
  node.pub.publish(ping);
}
template <>
void sized_reply(Node<std_msgs::String>& node, const std_msgs::String& ping) {
  static std_msgs::String replies[16];
  int code = ping.data.empty() ? 0 : ping.data[0] - 'A';
  if (code < 0 || code > 15) code = 0;
  if (replies[code].data.size() != (size_t(1) << code)) replies[code].data.assign(size_t(1) << code, 'x');
  node.pub.publish(replies[code]);
}

template <class M>
static int run_size(Node<M>& node, const std::string& mode, size_t size, long long n, bool mros);

template <class M>
static int run(const std::string& mode, const std::string& sizes, long long n, bool mros = false) {
  if (mode == "echo") {
    Node<M> node(true, "/ping", "/pong");
    node.mros = mros;
    ros::spin();
    return 0;
  }
  Node<M> node(false, "/pong", "/ping");
  node.wait_connected();
  size_t pos = 0;
  while (pos <= sizes.size()) {
    size_t comma = sizes.find(',', pos);
    if (comma == std::string::npos) comma = sizes.size();
    int rc = run_size(node, mode, std::strtoull(sizes.substr(pos, comma - pos).c_str(), nullptr, 10), n, mros);
    if (rc != 0) return rc;
    pos = comma + 1;
  }
  return 0;
}

template <class M>
static void ping_for(M& msg, size_t size) {
  fill(msg, size);
}
static void ping_for(std_msgs::String& msg, size_t size) {  // mROS mode: one byte naming the reply's size
  int code = 0;
  while ((size_t(1) << code) < size) ++code;
  msg.data.assign(1, char('A' + code));
}

template <class M>
static int run_size(Node<M>& node, const std::string& mode, size_t size, long long n, bool mros) {
  M msg;
  if (mros) {
    ping_for(msg, size);
  } else {
    fill(msg, size);
  }
  if (mode == "ping") {
    for (int i = 0; i < 20; ++i) {  // warm-up
      long long want = node.received + 1;
      node.pub.publish(msg);
      if (!node.wait_for(want, 5.0)) return 3;
    }
    std::printf("RTT %zu", size);
    for (long long i = 0; i < n; ++i) {
      long long want = node.received + 1;
      long long t0 = now_ns();
      node.pub.publish(msg);
      if (!node.wait_for(want, 5.0)) return 3;
      std::printf(" %lld", node.last_ns - t0);
    }
    std::printf("\n");
  } else {
    // the same burst twice: on the new connection ("BURST"), then again on the now warm one ("WARM")
    for (const char* label : {"BURST", "WARM"}) {
      long long start = node.received;
      long long t0 = now_ns();
      for (long long i = 0; i < n; ++i) {
        node.pub.publish(msg);
        ros::getGlobalCallbackQueue()->callAvailable(ros::WallDuration(0));
      }
      long long before = -1;
      while (ros::ok() && node.received != before) {  // until one quiet second
        before = node.received;
        node.wait_for(start + n, 1.0);
        if (node.received - start >= n) break;
      }
      std::printf("%s %zu %lld %.6f\n", label, size, node.received - start, (node.last_ns - t0) / 1e9);
      std::fflush(stdout);
    }
  }
  std::fflush(stdout);
  return 0;
}

int main(int argc, char** argv) {
  ros::init(argc, argv, "roscpp_echo", ros::init_options::AnonymousName);
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s echo|ping|burst string|image [size n]\n", argv[0]);
    return 2;
  }
  std::string mode = argv[1], type = argv[2];
  std::string sizes = argc > 3 ? argv[3] : "0";
  long long n = argc > 4 ? std::strtoll(argv[4], nullptr, 10) : 0;
  if (type == "image") return run<sensor_msgs::Image>(mode, sizes, n);
  if (type == "cloud") return run<sensor_msgs::PointCloud2>(mode, sizes, n);
  return run<std_msgs::String>(mode, sizes, n, type == "mros");
}
