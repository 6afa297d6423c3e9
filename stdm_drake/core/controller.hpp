// The MPC controller of control_step.hpp outside Python: the controller file `stdm-drake export --target
// controller` writes (the prediction model, the robot's description for the gravity torque, the MPC settings and
// limits), read by `load_controller`, and the control step of stdm_drake/closed_loop/policy.py (`MpcStep`: the
// offset-free disturbance estimate, the warm start shifted by one period, the gravity fallback) in `Controller`.
//
// The file is text, one entry per line after its first line ("# stdm-drake controller 1 ..."):
//   array NAME ROWS COLS v_1 ... v_(ROWS COLS)     (row-major; a scalar is 1 x 1)
//   text NAME VALUE
// stdm_drake/closed_loop/controller_file.py writes it and documents every name.
#pragma once

#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include "control_step.hpp"

namespace stdm {

constexpr const char* kControllerMarker = "# stdm-drake controller 1";

struct ControllerFile {
  std::map<std::string, RowMatrixXd> arrays;
  std::map<std::string, std::string> texts;

  const RowMatrixXd& array(const std::string& name) const {
    auto found = arrays.find(name);
    if (found == arrays.end()) throw std::runtime_error("controller file: no entry " + name);
    return found->second;
  }
  bool has(const std::string& name) const { return arrays.count(name) > 0; }
  double scalar(const std::string& name) const { return array(name)(0, 0); }
  VectorXd vector(const std::string& name) const {
    const RowMatrixXd& values = array(name);
    return Eigen::Map<const VectorXd>(values.data(), values.size());
  }
  std::vector<int> integers(const std::string& name) const {
    const VectorXd values = vector(name);
    std::vector<int> out(values.size());
    for (int i = 0; i < values.size(); ++i) out[i] = int(std::lround(values[i]));
    return out;
  }
  std::string text(const std::string& name) const {
    auto found = texts.find(name);
    if (found == texts.end()) throw std::runtime_error("controller file: no entry " + name);
    return found->second;
  }

  static ControllerFile read(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw std::runtime_error("cannot open " + path);
    std::string line;
    std::getline(in, line);
    if (line.rfind(kControllerMarker, 0) != 0)
      throw std::runtime_error(path + " is not a controller file of stdm-drake export (format 1)");
    ControllerFile file;
    while (std::getline(in, line)) {
      if (line.empty()) continue;
      std::istringstream words(line);
      std::string kind, name;
      words >> kind >> name;
      if (kind == "text") {
        std::string value;
        words >> value;
        file.texts[name] = value;
      } else if (kind == "array") {
        long rows = 0, cols = 0;
        words >> rows >> cols;
        if (!words || rows < 0 || cols < 0) throw std::runtime_error("controller file: bad entry " + name);
        RowMatrixXd values(rows, cols);
        for (long i = 0; i < rows * cols; ++i)
          if (!(words >> values.data()[i])) throw std::runtime_error("controller file: short entry " + name);
        file.arrays[name] = values;
      } else {
        throw std::runtime_error("controller file: unknown entry kind " + kind);
      }
    }
    return file;
  }
};

inline std::shared_ptr<RigidBody> load_rigid_body(const ControllerFile& file, const std::string& prefix) {
  auto body = std::make_shared<RigidBody>();
  const std::vector<int> parents = file.integers(prefix + "parents");
  body->build(parents, file.integers(prefix + "kinds"), file.array(prefix + "rotations"),
              file.array(prefix + "translations"), file.vector(prefix + "masses"), file.array(prefix + "centers"),
              file.array(prefix + "inertias"), file.vector(prefix + "armature"), file.vector(prefix + "gravity"));
  body->joints = int(parents.size());
  body->actuation = file.array(prefix + "actuation");
  body->actuators = int(body->actuation.cols());
  body->to_pin = file.integers(prefix + "to_pin");
  body->damping = file.vector(prefix + "damping");
  body->friction = file.vector(prefix + "friction");
  body->friction_scale = file.vector(prefix + "friction_scale");
  return body;
}

inline std::shared_ptr<Model> load_model(const ControllerFile& file) {
  const std::string kind = file.text("model");
  const int S = int(file.scalar("state_dim")), m = int(file.scalar("action_dim"));
  if (kind == "plant") {
    auto model = std::make_shared<PlantModel>();
    model->dynamics = load_rigid_body(file, "dynamics.");
    model->state_dim = S;
    model->action_dim = m;
    model->sample_period = file.scalar("sample_period");
    model->substeps = int(file.scalar("substeps"));
    return model;
  }
  if (kind != "network") throw std::runtime_error("controller file: unknown model " + kind);
  auto model = std::make_shared<NetworkModel>();
  Network& network = model->network;
  network.members = int(file.scalar("members"));
  const int layers = int(file.scalar("hidden_layers"));
  network.residual = file.scalar("residual") != 0.0;
  network.activation = activation_from_name(file.text("activation"));
  network.hidden_weight.resize(layers);
  network.hidden_bias.resize(layers);
  for (int e = 0; e < network.members; ++e) {
    const std::string member = "." + std::to_string(e);
    network.first.push_back(file.array("first" + member).cast<float>());
    network.mean_weight.push_back(file.array("mean_weight" + member).cast<float>());
    network.mean_bias.push_back(file.array("mean_bias" + member).cast<float>().row(0));
    for (int layer = 0; layer < layers; ++layer) {
      const std::string name = "." + std::to_string(layer) + member;
      network.hidden_weight[layer].push_back(file.array("hidden_weight" + name).cast<float>());
      network.hidden_bias[layer].push_back(file.array("hidden_bias" + name).cast<float>().row(0));
    }
  }
  network.inputs = int(network.first[0].rows()) - 1;
  network.width = int(network.first[0].cols());
  network.outputs = int(network.mean_weight[0].cols());
  network.finish();
  model->state_dim = S;
  model->action_dim = m;
  model->predicts_velocity = file.scalar("predicts_velocity") != 0.0;
  model->sample_period = file.scalar("sample_period");
  if (file.scalar("nominal") != 0.0) model->nominal = load_rigid_body(file, "dynamics.");
  return model;
}

// The controller of a file over a plan of reference states: `ControlStep` (policy.MpcStep) with its memory, and
// the gravity fallback from the robot's description.
struct Controller {
  RealTimeIteration rti;
  std::shared_ptr<RigidBody> description;   // the robot's description: the gravity torque
  ControlStep control;
  long k = 0;
  StepMemory memory;
  StepResult last;
  bool last_fallback = false;

  static Controller load(const std::string& path) {
    const ControllerFile file = ControllerFile::read(path);
    Controller controller;
    RealTimeIteration& rti = controller.rti;
    rti.model = load_model(file);
    rti.iterations = int(file.scalar("iterations"));
    rti.regularization = file.scalar("regularization");
    // (a file written before the multi-level iteration has no entry: the exact step)
    rti.jacobian_refresh = file.has("jacobian_refresh") ? int(file.scalar("jacobian_refresh")) : 0;
    rti.Q = file.vector("Q");
    rti.R = file.vector("R");
    rti.terminal_factor = file.scalar("terminal_factor");
    rti.effort_limit = file.vector("effort_limit");
    rti.constrained = file.scalar("constrained") != 0.0;
    rti.hard = file.scalar("hard") != 0.0;
    rti.lower = file.vector("lower");
    rti.upper = file.vector("upper");
    rti.penalty_weight = file.scalar("penalty_weight");
    controller.description = load_rigid_body(file, "description.");
    controller.control.horizon = int(file.scalar("horizon"));
    controller.control.disturbance_gain = file.scalar("disturbance_gain");
    return controller;
  }

  // the reference (T, S) states at the sample period; restarts the controller
  void start(const RowMatrixXd& reference) {
    control.reference = reference;
    const int n = rti.S() / 2, m = rti.m();
    control.feedforward.resize(reference.rows(), m);
    for (int t = 0; t < reference.rows(); ++t)
      control.feedforward.row(t) =
          description->gravity_torque(reference.row(t).head(n).transpose()).head(m).transpose();
    k = 0;
    memory = control.first_memory(rti.S());
    rti.working_rows.clear();
    rti.kept_A_.resize(0, 0);
    rti.kept_B_.resize(0, 0);
  }

  // the torque (m,) N m for the measured state x (S,) at the next sample
  VectorXd step(const VectorXd& x) {
    const int n = rti.S() / 2;
    VectorXd estimate, torque;
    last_fallback = !control.step(rti, k, x, memory, last, estimate);
    if (!last_fallback) {
      torque = last.u.row(0).transpose();
    } else {
      VectorXd q = x.head(n);
      for (int i = 0; i < n; ++i)
        if (std::isnan(q[i])) q[i] = 0.0;
        else if (std::isinf(q[i])) q[i] = q[i] > 0 ? std::numeric_limits<double>::max() : -std::numeric_limits<double>::max();
      torque = description->gravity_torque(q).head(rti.m());
      for (int j = 0; j < torque.size(); ++j)
        torque[j] = std::clamp(torque[j], -rti.effort_limit[j], rti.effort_limit[j]);
      memory = control.fallback_memory(rti, k, x, torque, estimate);
    }
    ++k;
    return torque;
  }
};

}  // namespace stdm
