// Python bindings of the compiled core (control_step.hpp): the module stdm_drake._core.
// stdm_drake/dynamics/compiled_core.py builds its models from the toolbox's, stdm_drake/closed_loop/compiled.py its
// solver from the MPC settings; nothing here is called per node or per step from Python.
#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include "control_step.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using stdm::RowMatrixXd;
using stdm::RowMatrixXf;
using Eigen::VectorXd;

namespace {

std::shared_ptr<stdm::RigidBody> make_rigid_body(
    const std::vector<int>& parents, const std::vector<int>& kinds, const RowMatrixXd& rotations,
    const RowMatrixXd& translations, const VectorXd& masses, const RowMatrixXd& centers, const RowMatrixXd& inertias,
    const VectorXd& armature, const VectorXd& gravity, const std::vector<int>& to_pin, const VectorXd& damping,
    const VectorXd& friction, const VectorXd& friction_scale, const RowMatrixXd& actuation) {
  const size_t n = parents.size();
  if (kinds.size() != n || size_t(rotations.rows()) != n || rotations.cols() != 9 || size_t(translations.rows()) != n ||
      translations.cols() != 3 || size_t(masses.size()) != n || size_t(centers.rows()) != n || centers.cols() != 3 ||
      size_t(inertias.rows()) != n || inertias.cols() != 9 || size_t(armature.size()) != n || gravity.size() != 3 ||
      to_pin.size() != n || size_t(damping.size()) != n || size_t(actuation.rows()) != n ||
      friction.size() != friction_scale.size() || (friction.size() && size_t(friction.size()) != n))
    throw std::invalid_argument("rigid body: inconsistent sizes");
  auto body = std::make_shared<stdm::RigidBody>();
  body->build(parents, kinds, rotations, translations, masses, centers, inertias, armature, gravity);
  body->joints = int(n);
  body->actuators = int(actuation.cols());
  body->to_pin = to_pin;
  body->damping = damping;
  body->friction = friction;
  body->friction_scale = friction_scale;
  body->actuation = actuation;
  return body;
}

stdm::Network make_network(const std::vector<RowMatrixXf>& first, const std::vector<std::vector<RowMatrixXf>>& hidden_weight,
                           const std::vector<std::vector<RowMatrixXf>>& hidden_bias,
                           const std::vector<RowMatrixXf>& mean_weight, const std::vector<RowMatrixXf>& mean_bias,
                           bool residual, const std::string& activation) {
  stdm::Network network;
  network.members = int(first.size());
  if (network.members < 1 || mean_weight.size() != first.size() || mean_bias.size() != first.size() ||
      hidden_weight.size() != hidden_bias.size())
    throw std::invalid_argument("network: inconsistent members or layers");
  network.inputs = int(first[0].rows()) - 1;
  network.width = int(first[0].cols());
  network.outputs = int(mean_weight[0].cols());
  network.residual = residual;
  network.activation = stdm::activation_from_name(activation);
  network.first = first;
  network.mean_weight = mean_weight;
  for (const auto& bias : mean_bias) network.mean_bias.push_back(bias.row(0));
  for (size_t layer = 0; layer < hidden_weight.size(); ++layer) {
    if (int(hidden_weight[layer].size()) != network.members || int(hidden_bias[layer].size()) != network.members)
      throw std::invalid_argument("network: a hidden layer without every member");
    network.hidden_weight.push_back(hidden_weight[layer]);
    std::vector<Eigen::RowVectorXf> biases;
    for (const auto& bias : hidden_bias[layer]) biases.push_back(bias.row(0));
    network.hidden_bias.push_back(biases);
  }
  network.finish();
  return network;
}

// a probabilistic ensemble's variance head (no members: a deterministic network)
void add_variance_head(stdm::Network& network, const std::vector<RowMatrixXf>& weight,
                       const std::vector<RowMatrixXf>& bias, const RowMatrixXf& min_logvar,
                       const RowMatrixXf& max_logvar, const Eigen::VectorXf& log_output_variance) {
  if (weight.empty() && bias.empty()) return;
  const int outputs = network.outputs;
  bool fits = int(weight.size()) == network.members && int(bias.size()) == network.members &&
              min_logvar.rows() == network.members && min_logvar.cols() == outputs &&
              max_logvar.rows() == network.members && max_logvar.cols() == outputs &&
              log_output_variance.size() == outputs;
  for (size_t e = 0; fits && e < weight.size(); ++e)
    fits = weight[e].rows() == network.width && weight[e].cols() == outputs && bias[e].size() == outputs;
  if (!fits) throw std::invalid_argument("network: the variance head does not fit the members");
  network.variance_weight = weight;
  for (const auto& row : bias) network.variance_bias.push_back(Eigen::Map<const Eigen::RowVectorXf>(row.data(), outputs));
  network.min_logvar = min_logvar;
  network.max_logvar = max_logvar;
  network.log_output_variance = log_output_variance.transpose();
}

std::tuple<RowMatrixXd, RowMatrixXd, RowMatrixXd> linearize(const stdm::Model& model, const RowMatrixXd& x,
                                                            const RowMatrixXd& u) {
  RowMatrixXd next, A, B;
  model.linearize(x, u, next, A, B);
  return {next, A, B};
}

}  // namespace

NB_MODULE(_core, module) {
  module.doc() = "The MPC's control step in compiled code (stdm_drake/closed_loop/core/control_step.hpp).";
  // (solvers held by Python objects alive at interpreter exit are not leaks worth a warning on every command)
  nb::set_leak_warnings(false);

  nb::class_<stdm::RigidBody>(module, "RigidBody")
      .def("acceleration", nb::overload_cast<const VectorXd&, const VectorXd&, const VectorXd&>(
                               &stdm::RigidBody::acceleration, nb::const_), "q"_a, "v"_a, "tau"_a)
      .def("acceleration_and_jacobian", [](const stdm::RigidBody& body, const VectorXd& q, const VectorXd& v,
                                           const VectorXd& tau) {
        VectorXd out;
        RowMatrixXd jacobian;
        body.acceleration_and_jacobian(q, v, tau, out, jacobian);
        return std::make_tuple(out, jacobian);
      });
  module.def("rigid_body", &make_rigid_body, "parents"_a, "kinds"_a, "rotations"_a, "translations"_a, "masses"_a,
             "centers"_a, "inertias"_a, "armature"_a, "gravity"_a, "to_pin"_a, "damping"_a, "friction"_a,
             "friction_scale"_a, "actuation"_a);

  nb::class_<stdm::Model>(module, "Model")
      .def("step", &stdm::Model::step, "x"_a, "u"_a)
      .def("linearize", &linearize, "x"_a, "u"_a)
      .def("step_rows", [](const stdm::Model& self, const RowMatrixXd& x, const RowMatrixXd& u) {
        if (x.cols() != self.state_dim || u.cols() != self.action_dim || u.rows() != x.rows())
          throw std::invalid_argument("step_rows: x (N, S) and u (N, m) do not fit the model");
        nb::gil_scoped_release release;
        return self.step_rows(x, u);
      }, "x"_a, "u"_a)
      .def_ro("state_dim", &stdm::Model::state_dim)
      .def_ro("action_dim", &stdm::Model::action_dim);

  nb::class_<stdm::NetworkModel, stdm::Model>(module, "NetworkModel")
      .def("__init__", [](stdm::NetworkModel* self, const std::vector<RowMatrixXf>& first,
                          const std::vector<std::vector<RowMatrixXf>>& hidden_weight,
                          const std::vector<std::vector<RowMatrixXf>>& hidden_bias,
                          const std::vector<RowMatrixXf>& mean_weight, const std::vector<RowMatrixXf>& mean_bias,
                          bool residual, const std::string& activation, int state_dim, int action_dim,
                          bool predicts_velocity, std::shared_ptr<stdm::RigidBody> nominal, double sample_period,
                          const std::vector<RowMatrixXf>& variance_weight, const std::vector<RowMatrixXf>& variance_bias,
                          const RowMatrixXf& min_logvar, const RowMatrixXf& max_logvar,
                          const Eigen::VectorXf& log_output_variance) {
        new (self) stdm::NetworkModel();
        self->network = make_network(first, hidden_weight, hidden_bias, mean_weight, mean_bias, residual, activation);
        add_variance_head(self->network, variance_weight, variance_bias, min_logvar, max_logvar, log_output_variance);
        self->state_dim = state_dim;
        self->action_dim = action_dim;
        self->predicts_velocity = predicts_velocity;
        self->nominal = nominal;
        self->sample_period = sample_period;
        const int n = state_dim / 2;
        const int expected = state_dim + action_dim + (nominal ? n : 0);
        const int outputs = predicts_velocity ? n : state_dim;
        if (self->network.inputs != expected || self->network.outputs != outputs)
          throw std::invalid_argument("network model: the network's sizes do not fit the structure");
      }, "first"_a, "hidden_weight"_a, "hidden_bias"_a, "mean_weight"_a, "mean_bias"_a, "residual"_a, "activation"_a,
         "state_dim"_a, "action_dim"_a, "predicts_velocity"_a, "nominal"_a.none(), "sample_period"_a,
         "variance_weight"_a = std::vector<RowMatrixXf>(), "variance_bias"_a = std::vector<RowMatrixXf>(),
         "min_logvar"_a = RowMatrixXf(), "max_logvar"_a = RowMatrixXf(),
         "log_output_variance"_a = Eigen::VectorXf())
      .def("rollout", [](const stdm::NetworkModel& self, const RowMatrixXd& x0, const RowMatrixXd& actions, int T) {
        if (x0.cols() != self.state_dim || actions.cols() != self.action_dim || T < 0 ||
            actions.rows() != x0.rows() * T)
          throw std::invalid_argument("rollout: x0 (B, S) and actions (B T, m) do not fit the model");
        RowMatrixXd mean, variance;
        {
          nb::gil_scoped_release release;
          self.rollout(x0, actions, T, mean, variance);
        }
        return std::make_tuple(mean, variance);
      }, "x0"_a, "actions"_a, "steps"_a);

  nb::class_<stdm::PlantModel, stdm::Model>(module, "PlantModel")
      .def("__init__", [](stdm::PlantModel* self, std::shared_ptr<stdm::RigidBody> dynamics, double sample_period,
                          int substeps) {
        new (self) stdm::PlantModel();
        self->dynamics = dynamics;
        self->state_dim = 2 * dynamics->joints;
        self->action_dim = dynamics->actuators;
        self->sample_period = sample_period;
        self->substeps = substeps;
      }, "dynamics"_a, "sample_period"_a, "substeps"_a);

  nb::class_<stdm::RealTimeIteration>(module, "RealTimeIteration")
      .def("__init__", [](stdm::RealTimeIteration* self, std::shared_ptr<stdm::Model> model, int iterations,
                          double regularization, const VectorXd& Q, const VectorXd& R, double terminal_factor,
                          const VectorXd& effort_limit, bool constrained, bool hard, const VectorXd& lower,
                          const VectorXd& upper, double penalty_weight, int jacobian_refresh) {
        new (self) stdm::RealTimeIteration();
        self->model = model;
        self->iterations = iterations;
        self->regularization = regularization;
        self->Q = Q;
        self->R = R;
        self->terminal_factor = terminal_factor;
        self->effort_limit = effort_limit;
        self->constrained = constrained;
        self->hard = hard;
        self->lower = lower;
        self->upper = upper;
        self->penalty_weight = penalty_weight;
        self->jacobian_refresh = jacobian_refresh;
      }, "model"_a, "iterations"_a, "regularization"_a, "Q"_a, "R"_a, "terminal_factor"_a, "effort_limit"_a,
         "constrained"_a, "hard"_a, "lower"_a, "upper"_a, "penalty_weight"_a, "jacobian_refresh"_a = 0)
      .def("solve", [](stdm::RealTimeIteration& self, const VectorXd& x0, const RowMatrixXd& u_init,
                       const RowMatrixXd& reference, const RowMatrixXd& u_ff, const VectorXd& offset,
                       std::optional<RowMatrixXd> x_init) {
        stdm::StepResult result;
        {
          nb::gil_scoped_release release;
          result = self.solve(x0, u_init, reference, u_ff, offset, x_init ? &*x_init : nullptr);
        }
        return std::make_tuple(result.u, result.x, result.cost, result.iterations, result.finite, result.active,
                               result.slack);
      }, "x0"_a, "u_init"_a, "reference"_a, "u_ff"_a, "offset"_a, "x_init"_a.none())
      .def("forget", [](stdm::RealTimeIteration& self) { self.working_rows.clear(); })
      .def_ro("unsettled", &stdm::RealTimeIteration::unsettled);

  // policy.MpcStep's control step in one call (the solver and the reference held; the memory passed in and out)
  struct BoundControlStep {
    std::shared_ptr<stdm::RealTimeIteration> rti;
    stdm::ControlStep control;
  };
  nb::class_<BoundControlStep>(module, "ControlStep")
      .def("__init__", [](BoundControlStep* self, std::shared_ptr<stdm::RealTimeIteration> rti,
                          const RowMatrixXd& reference, const RowMatrixXd& feedforward, int horizon,
                          double disturbance_gain) {
        new (self) BoundControlStep();
        self->rti = rti;
        self->control.reference = reference;
        self->control.feedforward = feedforward;
        self->control.horizon = horizon;
        self->control.disturbance_gain = disturbance_gain;
      }, "rti"_a, "reference"_a, "feedforward"_a, "horizon"_a, "disturbance_gain"_a)
      .def("step", [](BoundControlStep& self, long k, const VectorXd& x, const VectorXd& predicted,
                      const VectorXd& disturbance, const RowMatrixXd& plan, const RowMatrixXd& nodes) {
        stdm::StepMemory memory{predicted, disturbance, plan, nodes};
        stdm::StepResult result;
        VectorXd estimate;
        bool solved;
        {
          nb::gil_scoped_release release;
          solved = self.control.step(*self.rti, k, x, memory, result, estimate);
        }
        VectorXd torque = solved ? VectorXd(result.u.row(0).transpose()) : VectorXd();
        return std::make_tuple(solved, torque, memory.predicted, solved ? memory.disturbance : estimate, memory.plan,
                               memory.nodes, result.active, result.slack);
      }, "k"_a, "x"_a, "predicted"_a, "disturbance"_a, "plan"_a, "nodes"_a);
}
