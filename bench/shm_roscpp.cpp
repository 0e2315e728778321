// roscpp's side of `python -m bench.shm --latency` (compiled by the bench, never shipped).
//   pub <size> <count> [gap]  advertise /bench_shm (sensor_msgs/Image), wait for a subscriber, publish count + 1
//                       images gap seconds apart (default 0.02), each stamped (CLOCK_MONOTONIC seconds, a double in data[0..8]) just before
//                       publish(); then wait for a line on stdin
//   sub <count>         subscribe, print "lat [seconds, ...]" (receive time minus stamp) after count + 1 images
#include <ros/ros.h>
#include <sensor_msgs/Image.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <string>
#include <vector>

static double mono() {
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static std::vector<double> lat;
static size_t wanted = 0;

static void on_image(const sensor_msgs::Image::ConstPtr& msg) {
  double stamp = 0;
  if (msg->data.size() >= 8) std::memcpy(&stamp, msg->data.data(), 8);
  lat.push_back(mono() - stamp);
  if (lat.size() >= wanted) ros::shutdown();
}

int main(int argc, char** argv) {
  ros::init(argc, argv, "bench_shm_roscpp", ros::init_options::AnonymousName);
  std::string mode = argc > 1 ? argv[1] : "";
  ros::NodeHandle nh;
  if (mode == "pub" && argc > 3) {
    size_t size = std::strtoul(argv[2], nullptr, 10);
    int count = std::atoi(argv[3]);
    double gap = argc > 4 ? std::atof(argv[4]) : 0.02;
    ros::Publisher pub = nh.advertise<sensor_msgs::Image>("/bench_shm", 4);
    std::printf("addr - -\n");
    std::fflush(stdout);
    while (ros::ok() && pub.getNumSubscribers() == 0) ros::Duration(0.001).sleep();
    ros::Duration(0.2).sleep();
    sensor_msgs::Image img;
    img.encoding = "mono8";
    img.data.resize(size);
    for (int i = 0; i <= count && ros::ok(); ++i) {
      double t = mono();
      std::memcpy(img.data.data(), &t, 8);
      pub.publish(img);
      ros::Duration(gap).sleep();
    }
    char line[16];
    if (!std::fgets(line, sizeof line, stdin)) return 0;
    return 0;
  }
  if (mode == "sub" && argc > 2) {
    wanted = std::atoi(argv[2]) + 1;
    ros::Subscriber sub = nh.subscribe("/bench_shm", 4, on_image, ros::TransportHints().tcpNoDelay());
    ros::spin();
    std::printf("lat [");
    for (size_t i = 0; i < lat.size(); ++i) std::printf(i ? ", %.9f" : "%.9f", lat[i]);
    std::printf("]\n");
    std::fflush(stdout);
    return 0;
  }
  std::fprintf(stderr, "usage: pub <size> <count> | sub <count>\n");
  return 2;
}
