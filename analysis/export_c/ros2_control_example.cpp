// ros2_control_example.cpp: how the exported controller sits in a ros2_control controller.
//
// A documentation source, not built by the Makefile (it needs a ROS 2 workspace: controller_interface,
// hardware_interface, realtime_tools, pluginlib). The controller claims one effort command interface per
// joint and reads position and velocity state interfaces; update() runs at the control rate DVFC_PERIOD
// (set the controller manager's update_rate to 1 / DVFC_PERIOD) and calls dvfc_step once.
//
// Features come from a vision node (a message of DVFC_N_FEATURES doubles about the principal point,
// undistorted, and the sample index at which the image was exposed, e.g. from the camera's trigger): the
// subscriber callback writes them to a realtime buffer, update() takes the newest one once. On a
// non-zero return code the controller keeps commanding the (finite, gravity-compensating) torque and
// reports the code; what follows (a protective stop, the brakes) is the robot's safety layer's decision.
#include <array>
#include <memory>
#include <string>
#include <vector>

#include "controller_interface/controller_interface.hpp"
#include "realtime_tools/realtime_buffer.h"
#include "std_msgs/msg/float64_multi_array.hpp"

extern "C" {
#include "dvfc_controller.h"
}

namespace dvfc_ros {

struct Image {
  std::array<double, DVFC_N_FEATURES> features{};
  int capture_step = -1;
  bool fresh = false;
};

class DvfcController : public controller_interface::ControllerInterface {
 public:
  controller_interface::CallbackReturn on_init() override {
    auto_declare<std::vector<std::string>>("joints", {});
    return CallbackReturn::SUCCESS;
  }

  controller_interface::InterfaceConfiguration command_interface_configuration() const override {
    controller_interface::InterfaceConfiguration config{controller_interface::interface_configuration_type::INDIVIDUAL, {}};
    for (const auto& joint : joints_) config.names.push_back(joint + "/effort");
    return config;
  }

  controller_interface::InterfaceConfiguration state_interface_configuration() const override {
    controller_interface::InterfaceConfiguration config{controller_interface::interface_configuration_type::INDIVIDUAL, {}};
    for (const auto& joint : joints_) config.names.push_back(joint + "/position");
    for (const auto& joint : joints_) config.names.push_back(joint + "/velocity");
    return config;
  }

  controller_interface::CallbackReturn on_configure(const rclcpp_lifecycle::State&) override {
    joints_ = get_node()->get_parameter("joints").as_string_array();
    if (joints_.size() != DVFC_N_JOINTS) return CallbackReturn::ERROR;  // the export's joint order
    // Message layout: [capture_step, u_1, v_1, ..., u_m, v_m].
    subscription_ = get_node()->create_subscription<std_msgs::msg::Float64MultiArray>(
        "~/features", rclcpp::SensorDataQoS(), [this](const std_msgs::msg::Float64MultiArray& msg) {
          if (msg.data.size() != DVFC_N_FEATURES + 1) return;
          Image image;
          image.capture_step = static_cast<int>(msg.data[0]);
          for (int i = 0; i < DVFC_N_FEATURES; ++i) image.features[i] = msg.data[i + 1];
          image.fresh = true;
          buffer_.writeFromNonRT(image);
        });
    return CallbackReturn::SUCCESS;
  }

  controller_interface::CallbackReturn on_activate(const rclcpp_lifecycle::State&) override {
    dvfc_init(&state_);
    k_ = 0;
    return CallbackReturn::SUCCESS;
  }

  controller_interface::return_type update(const rclcpp::Time&, const rclcpp::Duration&) override {
    double q[DVFC_N_JOINTS], qd[DVFC_N_JOINTS], tau[DVFC_N_JOINTS];
    for (int i = 0; i < DVFC_N_JOINTS; ++i) {
      q[i] = state_interfaces_[i].get_value();
      qd[i] = state_interfaces_[DVFC_N_JOINTS + i].get_value();
    }
    Image* image = buffer_.readFromRT();  // lock-free on the real-time side
    const double* features = nullptr;
    int capture = -1;
    if (image && image->fresh) {
      features = image->features.data();
      capture = image->capture_step;
      image->fresh = false;  // each image is used once
    }
    const int code = dvfc_step(&state_, k_ * DVFC_PERIOD, q, qd, features, capture, tau);
    for (int i = 0; i < DVFC_N_JOINTS; ++i) command_interfaces_[i].set_value(tau[i]);
    ++k_;
    if (code > DVFC_IMAGE_REJECTED) return controller_interface::return_type::ERROR;  // safe torque written
    return controller_interface::return_type::OK;
  }

 private:
  std::vector<std::string> joints_;
  dvfc_state state_{};
  long k_ = 0;
  realtime_tools::RealtimeBuffer<Image> buffer_;
  rclcpp::Subscription<std_msgs::msg::Float64MultiArray>::SharedPtr subscription_;
};

}  // namespace dvfc_ros

#include "pluginlib/class_list_macros.hpp"
PLUGINLIB_EXPORT_CLASS(dvfc_ros::DvfcController, controller_interface::ControllerInterface)
