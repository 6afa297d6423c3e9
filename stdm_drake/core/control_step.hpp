// The compiled core: the prediction models' rollouts, batched steps and linearizations, and the MPC's control
// step, the real-time iteration with the robot's limits (Python: bindings.cpp binds it as stdm_drake._core;
// stdm_drake/dynamics/compiled_core.py builds its models, stdm_drake/closed_loop/compiled.py its solver; the numpy
// implementation, LearnedModel's rollouts and steps, closed_loop/rti.py and constraints.py, is the reference it
// is tested equal to).
//
// Shapes for n joints, m actuated, state S = 2n ([q rad, v rad/s]), horizon H: states (H+1, S), torques (H, m)
// N m, all matrices row-major as numpy lays them out.
//
// Models (the `Model` interface: `step` of one row, `step_rows` of independent rows, `linearize` of a horizon's
// rows; a NetworkModel's `rollout` of whole open-loop predictions):
//   NetworkModel  an ensemble MLP (float32, the normalizers folded into its first and last layers, as
//                 stdm_drake.learning.predict.InferenceModel holds it) as a state-transition model: the next
//                 state or the next velocity (the angle by the trapezoid rule), raw inputs or with the nominal
//                 acceleration phi = M(q)^-1 (B tau + tau_g - C v - D v) of the robot's rigid-body model; its
//                 Jacobian by reverse mode over the members (one matrix product per layer for the whole horizon)
//                 and, for phi, Pinocchio's analytic ABA derivatives by the chain rule.
//   PlantModel    the robot's rigid-body dynamics (Pinocchio's ABA, damping and smoothed Coulomb friction
//                 added) stepped by classical RK4 over the period, the stages' analytic Jacobians chained.
// The optimizer (`RealTimeIteration`): the multiple-shooting Gauss-Newton step by a Riccati recursion over the
// nodes (the numpy reference condenses it to the torques and solves it densely: the same minimizer); where a
// limit binds, the step condensed to the torques as a strictly convex QP (torque box hard, state rows soft with
// an exact penalty, or hard) solved by a dual active-set method (Goldfarb & Idnani 1983) with constraint
// generation of the state rows.
// `ControlStep`: policy.MpcStep's control step (disturbance estimate, warm start, memory) around it, so that a
// control step from Python is one call.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "rigid_body.hpp"
#include "small_gemm.hpp"

namespace stdm {

// ------------------------------------------------------------------------------------------------------------
// Activations, as stdm_drake.learning.activations applies them to the (scale-folded) pre-activation.

enum class Activation { tanh, sigmoid, relu, leaky_relu, softplus, selu, elu, gelu, swish };

inline Activation activation_from_name(const std::string& name) {
  static const char* names[] = {"tanh", "sigmoid", "relu", "leaky_relu", "softplus", "selu", "elu", "gelu", "swish"};
  for (int i = 0; i < 9; ++i)
    if (name == names[i]) return static_cast<Activation>(i);
  throw std::invalid_argument("unknown activation " + name);
}

constexpr float kLeakyReluSlope = 0.01f;
constexpr double kSeluScale = 1.0507009873554804934193349852946;
constexpr double kSeluAlpha = 1.6732632423543772848170429916717;

inline float sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }

// value and slope of the activation at pre-activation p (float32, as the numpy engine computes them)
inline void activate(Activation kind, float p, float& value, float& slope) {
  switch (kind) {
    case Activation::tanh: { float t = std::tanh(p); value = t; slope = 1.0f - t * t; return; }
    case Activation::sigmoid: { float s = sigmoid(p); value = s; slope = s * sigmoid(-p); return; }
    case Activation::relu: value = p > 0 ? p : 0.0f; slope = p > 0 ? 1.0f : 0.0f; return;
    case Activation::leaky_relu: value = p > 0 ? p : kLeakyReluSlope * p; slope = p > 0 ? 1.0f : kLeakyReluSlope; return;
    case Activation::softplus: value = std::max(p, 0.0f) + std::log1p(std::exp(-std::abs(p))); slope = sigmoid(p); return;
    case Activation::selu:
    case Activation::elu: {
      const float scale = kind == Activation::selu ? float(kSeluScale) : 1.0f;
      const float alpha = kind == Activation::selu ? float(kSeluAlpha) : 1.0f;
      if (p > 0) { value = scale * p; slope = scale; }
      else { value = scale * alpha * std::expm1(p); slope = value + scale * alpha; }
      return;
    }
    case Activation::gelu: {
      const float cdf = 0.5f * std::erfc(-p * float(M_SQRT1_2));
      value = p * cdf;
      slope = cdf + p * std::exp(-0.5f * p * p) * float(0.5 * M_2_SQRTPI * M_SQRT1_2);
      return;
    }
    case Activation::swish: {   // on the scaled pre-activation s = p / 2: s (1 + tanh s) = p sigmoid(p)
      const float t = std::tanh(p);
      value = p * t + p;
      slope = 1.0f + t + p * (1.0f - t * t);
      return;
    }
  }
}

// ------------------------------------------------------------------------------------------------------------
// An ensemble MLP in float32: E members of L hidden layers of width W over K inputs and a constant 1.

struct Network {
  int members = 1, inputs = 0, width = 0, outputs = 0;
  bool residual = true;
  Activation activation = Activation::swish;
  std::vector<RowMatrixXf> first;                          // per member (K + 1, W): inputs then the bias row
  std::vector<std::vector<RowMatrixXf>> hidden_weight;     // per layer, per member (W, W)
  std::vector<std::vector<RowMatrixXf>> hidden_transposed; // their transposes, row-major (`finish`): reverse mode
  std::vector<std::vector<Eigen::RowVectorXf>> hidden_bias;  // per layer, per member (W,)
  std::vector<RowMatrixXf> mean_weight;                    // per member (W, outputs)
  std::vector<Eigen::RowVectorXf> mean_bias;               // per member (outputs,)
  // probabilistic members' variance head (empty: deterministic): per member (W, outputs) and (outputs,), the
  // soft bounds of each member's log-variance (E, outputs) and 2 log of the output scale (outputs,)
  std::vector<RowMatrixXf> variance_weight;
  std::vector<Eigen::RowVectorXf> variance_bias;
  RowMatrixXf min_logvar, max_logvar;
  Eigen::RowVectorXf log_output_variance;

  bool probabilistic() const { return !variance_weight.empty(); }

  // after the weights are set: the transposed hidden weights reverse mode multiplies by
  void finish() {
    hidden_transposed.assign(hidden_weight.size(), {});
    for (size_t layer = 0; layer < hidden_weight.size(); ++layer)
      for (const RowMatrixXf& weight : hidden_weight[layer]) hidden_transposed[layer].push_back(weight.transpose());
  }

  // out (N, C) = in (N, K) times a layer's weight (K, C) (its first K rows: the first layer's bias row left out):
  // `small_gemm`
  static void product(const RowMatrixXf& in, const RowMatrixXf& weight, RowMatrixXf& out,
                      const RowMatrixXf* scale = nullptr, int group = 1) {
    out.resize(in.rows(), weight.cols());
    small_gemm(in.data(), in.cols(), weight.data(), weight.cols(), out.data(), out.cols(), int(in.rows()),
               int(in.cols()), int(weight.cols()), scale ? scale->data() : nullptr, scale ? scale->cols() : 0, group);
  }

  // the first layer's pre-activation (N, W) of member e at input rows z (N, K), its bias row added
  void first_layer(const RowMatrixXf& z, int e, RowMatrixXf& pre) const {
    product(z, first[e], pre);
    pre.rowwise() += first[e].row(inputs);
  }

  // the last hidden layer (N, W) of member e at input rows z (N, K); `pre` scratch
  void last_hidden(const RowMatrixXf& z, int e, RowMatrixXf& pre, RowMatrixXf& value) const {
    first_layer(z, e, pre);
    activate_all(pre, value, nullptr);
    for (size_t layer = 0; layer < hidden_weight.size(); ++layer) {
      product(value, hidden_weight[layer][e], pre);
      pre.rowwise() += hidden_bias[layer][e];
      activate_all(pre, value, nullptr);
    }
  }

  // Scratch of `mean_and_variance` (kept by the caller across the steps of a rollout: no allocation per step).
  struct Scratch {
    RowMatrixXf pre, value, raw;
    std::vector<RowMatrixXf> member;   // each member's output (N, outputs)
  };

  // The members' mean output (N, outputs) and, with `variance`, the predictive variance (N, outputs): the spread
  // of the members' outputs about their mean plus their mean predicted variance (as predict._predictive_variance),
  // residual not added, at input rows z (N, K) float32.
  void mean_and_variance(const RowMatrixXf& z, RowMatrixXf& mean, RowMatrixXf* variance, Scratch& s) const {
    const Eigen::Index count = z.rows();
    mean.setZero(count, outputs);
    const bool spread = variance && (members > 1 || probabilistic());
    if (variance) variance->setZero(count, outputs);
    s.member.resize(members);
    for (int e = 0; e < members; ++e) {
      last_hidden(z, e, s.pre, s.value);
      product(s.value, mean_weight[e], s.member[e]);
      s.member[e].rowwise() += mean_bias[e];
      mean += s.member[e];
      if (!spread || !probabilistic()) continue;
      // logvar = min + softplus(max - softplus(max - raw) - min), in float32
      product(s.value, variance_weight[e], s.raw);
      s.raw.rowwise() += variance_bias[e];
      for (Eigen::Index row = 0; row < count; ++row)
        for (int out = 0; out < outputs; ++out) {
          const float upper = max_logvar(e, out) - softplus(max_logvar(e, out) - s.raw(row, out));
          const float logvar = min_logvar(e, out) + softplus(upper - min_logvar(e, out));
          (*variance)(row, out) += std::exp(logvar + log_output_variance[out]);
        }
    }
    const float share = 1.0f / float(members);
    mean *= share;
    if (!spread) return;
    // the spread about the mean (two passes: no cancellation), plus the mean aleatoric variance
    for (int e = 0; e < members; ++e) variance->array() += (s.member[e] - mean).array().square();
    *variance *= share;
  }

  static float softplus(float x) { return std::max(x, 0.0f) + std::log1p(std::exp(-std::abs(x))); }

  // value (and slope) of the activation at every pre-activation: tanh and swish (the default) vectorized
  // (Eigen's float tanh), the others one by one (`activate`)
  void activate_all(const RowMatrixXf& pre, RowMatrixXf& value, RowMatrixXf* slope) const {
    value.resize(pre.rows(), pre.cols());
    if (slope) slope->resize(pre.rows(), pre.cols());
    if (activation == Activation::tanh || activation == Activation::swish) {
      value.array() = pre.array().tanh();
      if (activation == Activation::tanh) {
        if (slope) slope->array() = 1.0f - value.array().square();
      } else {
        if (slope) slope->array() = 1.0f + value.array() + pre.array() * (1.0f - value.array().square());
        value.array() = pre.array() * value.array() + pre.array();
      }
      return;
    }
    for (Eigen::Index i = 0; i < pre.size(); ++i) {
      float d;
      activate(activation, pre.data()[i], value.data()[i], d);
      if (slope) slope->data()[i] = d;
    }
  }

  // The members' mean output (N, outputs), residual not added, for input rows z (N, K) float32; with
  // `jacobian`, d mean / d z (N outputs, K) stacked row after row (the residual's identity included).
  void evaluate(const RowMatrixXf& z, RowMatrixXf& mean, RowMatrixXf* jacobian) const {
    if (!jacobian) {
      Scratch scratch;
      mean_and_variance(z, mean, nullptr, scratch);
      return;
    }
    const int count = int(z.rows()), layers = int(hidden_weight.size());
    mean.setZero(count, outputs);
    if (jacobian) jacobian->setZero(Eigen::Index(count) * outputs, inputs);
    std::vector<RowMatrixXf> slopes(layers + 1);
    RowMatrixXf pre, value, adjoint, next;
    const float share = 1.0f / float(members);
    for (int e = 0; e < members; ++e) {
      first_layer(z, e, pre);
      for (int layer = 0; layer <= layers; ++layer) {
        if (layer > 0) {
          product(value, hidden_weight[layer - 1][e], pre);
          pre.rowwise() += hidden_bias[layer - 1][e];
        }
        activate_all(pre, value, jacobian ? &slopes[layer] : nullptr);
      }
      RowMatrixXf member;
      product(value, mean_weight[e], member);
      member.rowwise() += mean_bias[e];
      mean += member;
      if (!jacobian) continue;
      // reverse mode: the adjoint rows (N outputs, W), each row one output of one input row
      adjoint.resize(Eigen::Index(count) * outputs, width);
      for (int row = 0; row < count; ++row)
        for (int out = 0; out < outputs; ++out)
          adjoint.row(row * outputs + out) = mean_weight[e].col(out).transpose().cwiseProduct(slopes[layers].row(row));
      for (int layer = layers; layer >= 1; --layer) {   // (each input row's `outputs` rows times its slopes)
        product(adjoint, hidden_transposed[layer - 1][e], next, &slopes[layer - 1], outputs);
        adjoint.swap(next);
      }
      jacobian->noalias() += adjoint * first[e].topRows(inputs).transpose();
    }
    mean *= share;
    if (jacobian) {
      *jacobian *= share;
      if (residual)
        for (int row = 0; row < count; ++row)
          for (int out = 0; out < outputs && out < inputs; ++out) (*jacobian)(row * outputs + out, out) += 1.0f;
    }
  }
};

// ------------------------------------------------------------------------------------------------------------
// Prediction models.

struct Model {
  int state_dim = 0, action_dim = 0;
  virtual ~Model() = default;
  // the next state (S,) of x (S,) under u (m,)
  virtual VectorXd step(const VectorXd& x, const VectorXd& u) const = 0;
  // every row of a horizon: next states (H, S), A (H S, S) and B (H S, m) stacked node after node
  virtual void linearize(const RowMatrixXd& x, const RowMatrixXd& u, RowMatrixXd& next, RowMatrixXd& A,
                         RowMatrixXd& B) const = 0;
  // the next states (N, S) of N independent rows x (N, S) under u (N, m) (sampling MPC's particles); a row that
  // is not finite gives NaN
  virtual RowMatrixXd step_rows(const RowMatrixXd& x, const RowMatrixXd& u) const {
    RowMatrixXd next(x.rows(), state_dim);
    for (Eigen::Index row = 0; row < x.rows(); ++row) {
      if (!x.row(row).allFinite() || !u.row(row).allFinite()) {
        next.row(row).setConstant(std::numeric_limits<double>::quiet_NaN());
        continue;
      }
      next.row(row) = step(x.row(row).transpose(), u.row(row).transpose()).transpose();
    }
    return next;
  }
};

struct NetworkModel : Model {
  Network network;
  bool predicts_velocity = true;          // else the state
  std::shared_ptr<RigidBody> nominal;     // null: raw inputs; else phi is an input
  double sample_period = 0.0;

  int joints() const { return state_dim / 2; }

  // the network's input row (float64) of x, u and phi: [x, u, (phi)] for the state, [v, q, u, (phi)] for the velocity
  void input_row(const VectorXd& x, const VectorXd& u, const VectorXd* phi, double* row) const {
    const int n = joints(), m = action_dim;
    int k = 0;
    if (predicts_velocity) {
      for (int i = 0; i < n; ++i) row[k++] = x[n + i];
      for (int i = 0; i < n; ++i) row[k++] = x[i];
    } else {
      for (int i = 0; i < 2 * n; ++i) row[k++] = x[i];
    }
    for (int i = 0; i < m; ++i) row[k++] = u[i];
    if (phi)
      for (int i = 0; i < n; ++i) row[k++] = (*phi)[i];
  }

  // the model's next state from the network's mean output (outputs,) in float64
  void assemble(const VectorXd& x, const double* mean, double* next) const {
    const int n = joints();
    if (!predicts_velocity) {
      for (int i = 0; i < 2 * n; ++i) next[i] = mean[i] + (network.residual ? x[i] : 0.0);
      return;
    }
    for (int i = 0; i < n; ++i) {
      const double velocity = double(float(mean[i])) + (network.residual ? x[n + i] : 0.0);
      next[n + i] = velocity;
      next[i] = x[i] + 0.5 * sample_period * (x[n + i] + velocity);
    }
  }

  VectorXd step(const VectorXd& x, const VectorXd& u) const override {
    const int width = network.inputs;
    VectorXd row(width), phi;
    if (nominal) phi = nominal->acceleration(x.head(joints()), x.tail(joints()), u);
    input_row(x, u, nominal ? &phi : nullptr, row.data());
    RowMatrixXf z = row.transpose().cast<float>(), mean;
    network.evaluate(z, mean, nullptr);
    VectorXd out(state_dim), mean64 = mean.row(0).transpose().cast<double>();
    assemble(x, mean64.data(), out.data());
    return out;
  }

  void linearize(const RowMatrixXd& x, const RowMatrixXd& u, RowMatrixXd& next, RowMatrixXd& A,
                 RowMatrixXd& B) const override {
    const int H = int(x.rows()), n = joints(), S = state_dim, m = action_dim, width = network.inputs;
    const int outputs = network.outputs, total = S + m;
    RowMatrixXd rows(H, width);
    std::vector<RowMatrixXd> phi_jacobian(nominal ? H : 0);
    for (int k = 0; k < H; ++k) {
      VectorXd xk = x.row(k).transpose(), uk = u.row(k).transpose(), phi;
      if (nominal) nominal->acceleration_and_jacobian(xk.head(n), xk.tail(n), uk, phi, phi_jacobian[k]);
      input_row(xk, uk, nominal ? &phi : nullptr, rows.row(k).data());
    }
    RowMatrixXf z = rows.cast<float>(), mean, jacobian;
    network.evaluate(z, mean, &jacobian);
    next.resize(H, S);
    A.resize(Eigen::Index(H) * S, S);
    B.resize(Eigen::Index(H) * S, m);
    RowMatrixXd inputs = RowMatrixXd::Zero(width, total);   // d(network inputs) / d(x, u)
    if (predicts_velocity) {
      for (int i = 0; i < n; ++i) { inputs(i, n + i) = 1.0; inputs(n + i, i) = 1.0; }
    } else {
      for (int i = 0; i < S; ++i) inputs(i, i) = 1.0;
    }
    for (int i = 0; i < m; ++i) inputs(S + i, S + i) = 1.0;
    RowMatrixXd chained(outputs, total), full(S, total);
    for (int k = 0; k < H; ++k) {
      VectorXd xk = x.row(k).transpose();
      VectorXd mean64 = mean.row(k).transpose().cast<double>();
      assemble(xk, mean64.data(), next.row(k).data());
      if (nominal) inputs.bottomRows(n) = phi_jacobian[k];
      chained.noalias() = jacobian.middleRows(Eigen::Index(k) * outputs, outputs).cast<double>() * inputs;
      if (predicts_velocity) {
        full.bottomRows(n) = chained;
        full.topRows(n) = 0.5 * sample_period * chained;
        for (int i = 0; i < n; ++i) {
          full(i, i) += 1.0;
          full(i, n + i) += 0.5 * sample_period;
        }
      } else {
        full = chained;
      }
      A.middleRows(Eigen::Index(k) * S, S) = full.leftCols(S);
      B.middleRows(Eigen::Index(k) * S, S) = full.rightCols(m);
    }
  }

  // The buffers of `step_batch`, kept by the caller across the steps of a rollout (no allocation per step).
  struct BatchScratch {
    Network::Scratch network;
    RowMatrixXd rows, outputs;
    RowMatrixXf z, mean, spread;
    VectorXd xk, uk, phi, mean64;
  };

  // The next states (N, S) of finite rows x (N, S) under u (N, m), one matrix product per layer for all rows,
  // and with `variance` their one-step predictive variance (N, S) (zero for one deterministic member).
  void step_batch(const RowMatrixXd& x, const RowMatrixXd& u, RowMatrixXd& next, RowMatrixXd* variance,
                  BatchScratch& s) const {
    const int N = int(x.rows()), n = joints();
    s.rows.resize(N, network.inputs);
    for (int i = 0; i < N; ++i) {
      s.xk = x.row(i).transpose();
      s.uk = u.row(i).transpose();
      if (nominal) s.phi = nominal->acceleration(s.xk.head(n), s.xk.tail(n), s.uk);
      input_row(s.xk, s.uk, nominal ? &s.phi : nullptr, s.rows.row(i).data());
    }
    s.z = s.rows.cast<float>();
    network.mean_and_variance(s.z, s.mean, variance ? &s.spread : nullptr, s.network);
    next.resize(N, state_dim);
    for (int i = 0; i < N; ++i) {
      s.xk = x.row(i).transpose();
      s.mean64 = s.mean.row(i).transpose().cast<double>();
      assemble(s.xk, s.mean64.data(), next.row(i).data());
    }
    if (!variance) return;
    s.outputs = s.spread.cast<double>();   // the velocity's, or the state's
    variance->resize(N, state_dim);
    if (predicts_velocity) {
      variance->leftCols(n) = (0.25 * sample_period * sample_period) * s.outputs;
      variance->rightCols(n) = s.outputs;
    } else {
      *variance = s.outputs;
    }
  }

  // the batched step of independent rows; a row that is not finite gives NaN
  RowMatrixXd step_rows(const RowMatrixXd& x, const RowMatrixXd& u) const override {
    std::vector<int> finite;
    for (Eigen::Index row = 0; row < x.rows(); ++row)
      if (x.row(row).allFinite() && u.row(row).allFinite()) finite.push_back(int(row));
    RowMatrixXd next = RowMatrixXd::Constant(x.rows(), state_dim, std::numeric_limits<double>::quiet_NaN()), stepped;
    BatchScratch scratch;
    step_batch(x(finite, Eigen::all), u(finite, Eigen::all), stepped, nullptr, scratch);
    next(finite, Eigen::all) = stepped;
    return next;
  }

  // Open-loop prediction of steps 1..T of B rows under the ensemble's mean ("mean" propagation, as
  // dynamics.model.DynamicsModel.rollout): x0 (B, S), actions (B T, m) row b T + k; mean and variance (B T, S)
  // row b T + k (the one-step predictive variance at each step's mean state; zero for one deterministic
  // member). A row whose state leaves the finite numbers holds NaN from the step after on. The B rows step
  // together (`step_batch`).
  void rollout(const RowMatrixXd& x0, const RowMatrixXd& actions, int T, RowMatrixXd& mean,
               RowMatrixXd& variance) const {
    const int B = int(x0.rows()), m = action_dim;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    mean.setConstant(Eigen::Index(B) * T, state_dim, nan);
    variance.setConstant(Eigen::Index(B) * T, state_dim, nan);
    std::vector<int> going(B), still;
    for (int b = 0; b < B; ++b) going[b] = b;
    RowMatrixXd current = x0, u, next, spread;
    BatchScratch scratch;
    for (int k = 0; k < T && !going.empty(); ++k) {
      const int G = int(going.size());
      if (current.rows() != G) {   // (rows left the finite numbers: the others' states, in order)
        RowMatrixXd kept(G, state_dim);
        for (int i = 0; i < G; ++i) kept.row(i) = mean.row(Eigen::Index(going[i]) * T + k - 1);
        current.swap(kept);
      }
      u.resize(G, m);
      for (int i = 0; i < G; ++i) u.row(i) = actions.row(Eigen::Index(going[i]) * T + k);
      step_batch(current, u, next, &spread, scratch);
      still.clear();
      for (int i = 0; i < G; ++i) {
        const Eigen::Index row = Eigen::Index(going[i]) * T + k;
        mean.row(row) = next.row(i);
        variance.row(row) = spread.row(i);
        if (next.row(i).allFinite()) still.push_back(going[i]);
      }
      going.swap(still);
      current.swap(next);
    }
  }
};

struct PlantModel : Model {
  std::shared_ptr<RigidBody> dynamics;
  double sample_period = 0.0;
  int substeps = 1;

  VectorXd step(const VectorXd& x, const VectorXd& u) const override {
    VectorXd out(state_dim);
    step_into(x, u, out);
    return out;
  }

  RowMatrixXd step_rows(const RowMatrixXd& x, const RowMatrixXd& u) const override {
    RowMatrixXd next(x.rows(), state_dim);
    for (Eigen::Index row = 0; row < x.rows(); ++row) {
      if (!x.row(row).allFinite() || !u.row(row).allFinite()) {
        next.row(row).setConstant(std::numeric_limits<double>::quiet_NaN());
        continue;
      }
      step_into(x.row(row).transpose(), u.row(row).transpose(), next.row(row).transpose());
    }
    return next;
  }

  // `step` into out (S,) with no allocation once the workspace is sized (the predictions at every node)
  void step_into(const Eigen::Ref<const VectorXd>& x, const Eigen::Ref<const VectorXd>& u,
                 Eigen::Ref<VectorXd> out) const {
    const int n = state_dim / 2;
    const double h = sample_period / substeps;
    Stages& w = stages_;
    w.resize(n);
    w.q = x.head(n);
    w.v = x.tail(n);
    for (int s = 0; s < substeps; ++s) {
      dynamics->acceleration(w.q, w.v, u, w.a1);
      w.v2 = w.v + 0.5 * h * w.a1;
      w.at = w.q + 0.5 * h * w.v;
      dynamics->acceleration(w.at, w.v2, u, w.a2);
      w.v3 = w.v + 0.5 * h * w.a2;
      w.at = w.q + 0.5 * h * w.v2;
      dynamics->acceleration(w.at, w.v3, u, w.a3);
      w.v4 = w.v + h * w.a3;
      w.at = w.q + h * w.v3;
      dynamics->acceleration(w.at, w.v4, u, w.a4);
      w.q += h / 6.0 * (w.v + 2.0 * w.v2 + 2.0 * w.v3 + w.v4);
      w.v += h / 6.0 * (w.a1 + 2.0 * w.a2 + 2.0 * w.a3 + w.a4);
    }
    out.head(n) = w.q;
    out.tail(n) = w.v;
  }

  // the RK4 stages' vectors (n,) of `step_into`, kept between calls (the model is used by one thread, as the
  // rigid-body workspace it steps)
  struct Stages {
    VectorXd q, v, at, v2, v3, v4, a1, a2, a3, a4;
    void resize(int n) {
      if (q.size() == n) return;
      for (VectorXd* vector : {&q, &v, &at, &v2, &v3, &v4, &a1, &a2, &a3, &a4}) vector->resize(n);
    }
  };
  mutable Stages stages_;

  // x' = f(x) and d x' / d(x0, u) through the chain d x / d(x0, u) (S, S + m)
  void slope(const VectorXd& state, const VectorXd& u, const RowMatrixXd& chain, VectorXd& rate,
             RowMatrixXd& d_rate) const {
    const int n = state_dim / 2, S = state_dim, m = action_dim;
    VectorXd acceleration;
    RowMatrixXd jacobian;
    dynamics->acceleration_and_jacobian(state.head(n), state.tail(n), u, acceleration, jacobian);
    rate.resize(S);
    rate << state.tail(n), acceleration;
    d_rate.resize(S, S + m);
    d_rate.topRows(n) = chain.bottomRows(n);
    d_rate.bottomRows(n).noalias() = jacobian.leftCols(S) * chain;
    d_rate.bottomRows(n).rightCols(m) += jacobian.rightCols(m);
  }

  void linearize(const RowMatrixXd& x, const RowMatrixXd& u, RowMatrixXd& next, RowMatrixXd& A,
                 RowMatrixXd& B) const override {
    const int H = int(x.rows()), S = state_dim, m = action_dim;
    const double h = sample_period / substeps;
    next.resize(H, S);
    A.resize(Eigen::Index(H) * S, S);
    B.resize(Eigen::Index(H) * S, m);
    VectorXd k1, k2, k3, k4;
    RowMatrixXd d1, d2, d3, d4;
    for (int k = 0; k < H; ++k) {
      VectorXd state = x.row(k).transpose(), uk = u.row(k).transpose();
      RowMatrixXd total = RowMatrixXd::Zero(S, S + m);
      total.leftCols(S).setIdentity();
      for (int s = 0; s < substeps; ++s) {
        slope(state, uk, total, k1, d1);
        slope(state + 0.5 * h * k1, uk, total + 0.5 * h * d1, k2, d2);
        slope(state + 0.5 * h * k2, uk, total + 0.5 * h * d2, k3, d3);
        slope(state + h * k3, uk, total + h * d3, k4, d4);
        state = state + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
        total = total + h / 6.0 * (d1 + 2.0 * d2 + 2.0 * d3 + d4);
      }
      next.row(k) = state.transpose();
      A.middleRows(Eigen::Index(k) * S, S) = total.leftCols(S);
      B.middleRows(Eigen::Index(k) * S, S) = total.rightCols(m);
    }
  }
};

// ------------------------------------------------------------------------------------------------------------
// A strictly convex QP by the dual active-set method of Goldfarb & Idnani (1983):
//   min 1/2 y^T G y + a^T y   s.t.  lower <= y <= upper (each side may be infinite),  C^T y >= b
// (G (N, N) positive definite, given by J0 = L^-T (L L^T = G) and the unconstrained minimum y0 = -G^-1 a; C
// (N, P)). From the unconstrained minimum, the most violated constraint enters (violations measured along each
// normal; the bounds first, lower then upper of each variable in turn, then C's columns); partial steps drop the
// constraints whose multiplier would turn negative. J (J0 to start) and the upper-triangular R (with J's first
// columns spanning the active constraints' normals) are updated by Givens rotations. The bounds are rows of the
// identity: their values, J^T c and z^T c are single entries, so a scan over them costs N, not N^2. Exact to
// round-off; finite.

struct DualActiveSet {
  enum Status { optimal = 1, infeasible = -1, iteration_limit = -4, not_positive_definite = -6 };

  // J0 = L^-T and y0 = -G^-1 a of G (N, N); false where G is not positive definite
  static bool factor(const Eigen::MatrixXd& G, const VectorXd& a, Eigen::MatrixXd& J0, VectorXd& y0) {
    const int N = int(G.rows());
    Eigen::LLT<Eigen::MatrixXd> llt(G);
    if (llt.info() != Eigen::Success) return false;
    J0 = llt.matrixL().solve(Eigen::MatrixXd::Identity(N, N)).transpose();
    y0 = -llt.solve(a);
    return true;
  }

  // y (N,) and the status; `iterations` counts the constraints added and dropped; at most `limit` of them
  static Status solve(const Eigen::MatrixXd& J0, const VectorXd& y0, const VectorXd& lower, const VectorXd& upper,
                      const Eigen::MatrixXd& C, const VectorXd& b, VectorXd& y, int limit, int& iterations) {
    const int N = int(J0.rows()), P = int(C.cols()), bounds = 2 * N;
    iterations = 0;
    Eigen::MatrixXd J = J0;
    y = y0;
    Eigen::MatrixXd R = Eigen::MatrixXd::Zero(N, N);
    std::vector<int> active;                            // constraint p: bound p (< 2 N: variable p / 2, lower if
    std::vector<char> is_active(bounds + P, 0);         // p even, upper if odd), or C's column p - 2 N
    VectorXd u(0), d(N), z(N), r, values(P);
    VectorXd inverse_norm(P);
    for (int j = 0; j < P; ++j) inverse_norm[j] = 1.0 / std::max(C.col(j).norm(), 1e-300);
    const double tolerance = 1e-12;
    // c_p^T y - b_p (the constraint's slack) and its normal's norm
    auto slack_of = [&](int p) {
      if (p >= bounds) return C.col(p - bounds).dot(y) - b[p - bounds];
      return p % 2 == 0 ? y[p / 2] - lower[p / 2] : upper[p / 2] - y[p / 2];
    };
    auto along = [&](int p, const VectorXd& v) {       // c_p^T v
      if (p >= bounds) return C.col(p - bounds).dot(v);
      return p % 2 == 0 ? v[p / 2] : -v[p / 2];
    };
    auto normal_norm = [&](int p) { return p >= bounds ? 1.0 / inverse_norm[p - bounds] : 1.0; };

    auto givens = [](double& x, double& w, double& c, double& s) {
      const double h = std::hypot(x, w);
      if (h == 0.0) { c = 1.0; s = 0.0; return; }
      c = x / h; s = w / h; x = h; w = 0.0;
    };
    auto drop = [&](int l) {    // remove active[l]: R's column l out, upper-triangular again, J rotated alike
      const int q = int(active.size());
      is_active[active[l]] = 0;
      active.erase(active.begin() + l);
      for (int j = l; j < q - 1; ++j) R.col(j) = R.col(j + 1);
      R.col(q - 1).setZero();
      for (int j = l; j < q - 1; ++j) {
        double c, s;
        double x = R(j, j), w = R(j + 1, j);
        givens(x, w, c, s);
        for (int k = j; k < q - 1; ++k) {
          const double top = R(j, k), bottom = R(j + 1, k);
          R(j, k) = c * top + s * bottom;
          R(j + 1, k) = -s * top + c * bottom;
        }
        R(j + 1, j) = 0.0;
        for (int row = 0; row < N; ++row) {
          const double left = J(row, j), right = J(row, j + 1);
          J(row, j) = c * left + s * right;
          J(row, j + 1) = -s * left + c * right;
        }
      }
      VectorXd shorter(q - 1);
      for (int j = 0, k = 0; j < q; ++j)
        if (j != l) shorter[k++] = u[j];
      u = shorter;
    };

    while (true) {
      // 1. the most violated constraint (violation measured along its normal), in the order of the indices
      int p = -1;
      double worst = -tolerance;
      for (int i = 0; i < N; ++i) {
        if (!is_active[2 * i]) {
          const double s = y[i] - lower[i];
          if (s < worst) { worst = s; p = 2 * i; }
        }
        if (!is_active[2 * i + 1]) {
          const double s = upper[i] - y[i];
          if (s < worst) { worst = s; p = 2 * i + 1; }
        }
      }
      if (P) {
        values.noalias() = C.transpose() * y;
        for (int j = 0; j < P; ++j) {
          if (is_active[bounds + j]) continue;
          const double s = (values[j] - b[j]) * inverse_norm[j];
          if (s < worst) { worst = s; p = bounds + j; }
        }
      }
      if (p < 0) return optimal;
      VectorXd u_plus(active.size() + 1);
      u_plus.head(active.size()) = u;
      u_plus[active.size()] = 0.0;
      while (true) {
        if (iterations >= limit) return iteration_limit;
        const int q = int(active.size());
        // 2(a) directions: primal z in the null space of the active normals, dual r
        if (p >= bounds) d.noalias() = J.transpose() * C.col(p - bounds);
        else if (p % 2 == 0) d = J.row(p / 2).transpose();
        else d = -J.row(p / 2).transpose();
        z.noalias() = J.rightCols(N - q) * d.tail(N - q);
        r = R.topLeftCorner(q, q).triangularView<Eigen::Upper>().solve(d.head(q));
        // 2(b) the partial step (a multiplier reaching zero) and the full step (constraint p met)
        double t1 = std::numeric_limits<double>::infinity();
        int l = -1;
        for (int j = 0; j < q; ++j)
          if (r[j] > tolerance && u_plus[j] / r[j] < t1) { t1 = u_plus[j] / r[j]; l = j; }
        const double curvature = along(p, z);
        const double slack = slack_of(p);
        const bool moves = z.norm() > 1e-14 * std::max(1.0, normal_norm(p)) && curvature > 0.0;
        const double t2 = moves ? -slack / curvature : std::numeric_limits<double>::infinity();
        const double t = std::min(t1, t2);
        if (!std::isfinite(t)) return infeasible;
        ++iterations;
        if (!moves) {        // a dual step only: drop the constraint whose multiplier reaches zero
          u_plus.head(q) -= t * r;
          u_plus[q] += t;
          VectorXd kept = u_plus;
          u = u_plus.head(q);
          drop(l);
          u_plus.resize(active.size() + 1);
          u_plus.head(active.size()) = u;
          u_plus[active.size()] = kept[q];
          continue;
        }
        y += t * z;
        u_plus.head(q) -= t * r;
        u_plus[q] += t;
        if (t2 <= t1) {      // the full step: p enters the active set
          // zero d below position q by rotations of J's columns (from the bottom up)
          for (int j = N - 1; j > q; --j) {
            double c, s;
            double x = d[j - 1], w = d[j];
            givens(x, w, c, s);
            d[j - 1] = x; d[j] = 0.0;
            for (int row = 0; row < N; ++row) {
              const double left = J(row, j - 1), right = J(row, j);
              J(row, j - 1) = c * left + s * right;
              J(row, j) = -s * left + c * right;
            }
          }
          R.col(q).head(q + 1) = d.head(q + 1);
          active.push_back(p);
          is_active[p] = 1;
          u = u_plus;
          break;
        }
        // the partial step: drop constraint l and try p again from here
        const double entering = u_plus[q];
        u = u_plus.head(q);
        drop(l);
        u_plus.resize(active.size() + 1);
        u_plus.head(active.size()) = u;
        u_plus[active.size()] = entering;
      }
    }
  }
};

// ------------------------------------------------------------------------------------------------------------
// The real-time iteration (stdm_drake/closed_loop/rti.py, the reference).

constexpr double kActiveTolerance = 1e-9;   // constraints.ACTIVE_TOLERANCE
constexpr int kMaxRounds = 20;              // constraints.MAX_ROUNDS
constexpr int kMaxQpIterations = 300;       // constraints.MAX_QP_ITERATIONS (here: the dual method's changes)

struct StepResult {
  RowMatrixXd u, x;
  double cost = std::numeric_limits<double>::infinity();
  int iterations = 0;
  bool finite = false, active = false;
  double slack = 0.0;
};

struct RealTimeIteration {
  std::shared_ptr<Model> model;
  int iterations = 1;
  double regularization = 1e-6;
  VectorXd Q, R;                   // the cost's diagonals (S,), (m,)
  double terminal_factor = 1.0;
  VectorXd effort_limit;           // (m,)
  bool constrained = false;        // false: mode off (torques clipped after the step, no state limit)
  bool hard = false;
  VectorXd lower, upper;           // state bounds (S,)
  double penalty_weight = 1e5;
  std::vector<int> working_rows;   // the last solve's state rows near or beyond their bounds (warm start)
  long unsettled = 0;              // QPs whose state rows did not settle within the budget (the box alone kept)
  // The multi-level iteration (rti.Rti.jacobian_refresh): 0 computes every node's Jacobians in every iteration
  // (the exact step); K > 0 those of `refreshed_nodes` only, the others kept from the last solve shifted by one
  // period (kept_A_ (H S, S), kept_B_ (H S, m); empty: none to reuse, as after a failed or cold solve).
  int jacobian_refresh = 0;
  RowMatrixXd kept_A_, kept_B_;

  int S() const { return model->state_dim; }
  int m() const { return model->action_dim; }

  RowMatrixXd clip(const RowMatrixXd& u) const {
    RowMatrixXd out = u;
    for (int k = 0; k < out.rows(); ++k)
      for (int j = 0; j < out.cols(); ++j) out(k, j) = std::clamp(out(k, j), -effort_limit[j], effort_limit[j]);
    return out;
  }

  double violation(double value, int component) const {
    return std::max(value - upper[component], 0.0) + std::max(lower[component] - value, 0.0);
  }

  double cost(const RowMatrixXd& x, const RowMatrixXd& u, const RowMatrixXd& reference, const RowMatrixXd& u_ff) const {
    const int H = int(u.rows());
    double state = 0.0, effort = 0.0, slack = 0.0, squares = 0.0;
    for (int k = 0; k < H; ++k) {
      const double weight = k == H - 1 ? terminal_factor : 1.0;
      double node = 0.0;
      for (int i = 0; i < S(); ++i) {
        const double e = x(k + 1, i) - reference(k + 1, i);
        node += Q[i] * e * e;
        if (constrained) {
          const double s = violation(x(k + 1, i), i);
          slack += s;
          squares += s * s;
        }
      }
      state += weight * node;
      for (int j = 0; j < m(); ++j) {
        const double e = u(k, j) - u_ff(k, j);
        effort += R[j] * e * e;
      }
    }
    double value = state + effort;
    if (constrained) value += penalty_weight * (slack + 0.5 * squares);
    return value;
  }

  RowMatrixXd rollout(const VectorXd& x0, const RowMatrixXd& u, const VectorXd& offset) const {
    RowMatrixXd x(u.rows() + 1, S());
    x.row(0) = x0.transpose();
    for (int k = 0; k < u.rows(); ++k)
      x.row(k + 1) = (model->step(x.row(k).transpose(), u.row(k).transpose()) + offset).transpose();
    return x;
  }

  // The nodes whose Jacobians an iteration computes under jacobian_refresh K over H nodes: every k with k mod P = 0,
  // P = ceil(H / K), and the newest, H - 1 (whose shifted predecessor does not exist). A node moves down one
  // position per control step, so each is refreshed at least every P steps. All H where K is 0 or P is 1.
  std::vector<int> refreshed_nodes(int H) const {
    const int period = jacobian_refresh > 0 ? (H + jacobian_refresh - 1) / jacobian_refresh : 1;
    std::vector<int> nodes;
    for (int k = 0; k < H; ++k)
      if (k % period == 0 || k == H - 1) nodes.push_back(k);
    return nodes;
  }

  // The predictions F (H, S) at every node of x (H+1, S), u (H, m) (the model's forward step; the linearization's
  // own at the refreshed `nodes`) and the Jacobians of `nodes` written into A (H S, S), B (H S, m).
  void linearize_nodes(const RowMatrixXd& x, const RowMatrixXd& u, const std::vector<int>& nodes,
                       RowMatrixXd& following, RowMatrixXd& A, RowMatrixXd& B) const {
    const int H = int(u.rows()), s = S();
    std::vector<int> others;
    for (int k = 0, i = 0; k < H; ++k) {
      if (i < int(nodes.size()) && nodes[i] == k) ++i;
      else others.push_back(k);
    }
    RowMatrixXd next, nodes_A, nodes_B;
    model->linearize(x(nodes, Eigen::all), u(nodes, Eigen::all), next, nodes_A, nodes_B);
    following.resize(H, s);
    following(nodes, Eigen::all) = next;
    if (!others.empty()) following(others, Eigen::all) = model->step_rows(x(others, Eigen::all), u(others, Eigen::all));
    for (size_t i = 0; i < nodes.size(); ++i) {
      A.middleRows(Eigen::Index(nodes[i]) * s, s) = nodes_A.middleRows(Eigen::Index(i) * s, s);
      B.middleRows(Eigen::Index(nodes[i]) * s, s) = nodes_B.middleRows(Eigen::Index(i) * s, s);
    }
  }

  StepResult solve(const VectorXd& x0, const RowMatrixXd& u_init, const RowMatrixXd& reference,
                   const RowMatrixXd& u_ff, const VectorXd& offset, const RowMatrixXd* x_init) {
    StepResult result;
    RowMatrixXd u = clip(u_init), x;
    const bool warm = x_init != nullptr && x_init->allFinite();
    if (!warm) {
      x = rollout(x0, u, offset);
    } else {
      x = *x_init;
      x.row(0) = x0.transpose();
    }
    const int H = int(u.rows()), s = S();
    const std::vector<int> nodes = refreshed_nodes(H);
    const bool partial = int(nodes.size()) < H;
    RowMatrixXd following, A, B;
    // the kept Jacobians shifted by one period (node k's are the last solve's node k + 1's), from a warm start only
    const bool reuse = partial && warm && kept_A_.rows() == Eigen::Index(H) * s && kept_A_.cols() == s;
    if (reuse) {
      A.resize(Eigen::Index(H) * s, s);
      B.resize(Eigen::Index(H) * s, m());
      A.topRows(Eigen::Index(H - 1) * s) = kept_A_.bottomRows(Eigen::Index(H - 1) * s);
      B.topRows(Eigen::Index(H - 1) * s) = kept_B_.bottomRows(Eigen::Index(H - 1) * s);
    }
    kept_A_.resize(0, 0);
    kept_B_.resize(0, 0);
    if (!x.allFinite()) {
      result.u = u; result.x = x; result.iterations = 0;
      return result;
    }
    double mu = regularization;
    int iteration = 0;
    bool active = false;
    double slack = 0.0;
    for (iteration = 1; iteration <= iterations; ++iteration) {
      bool stepped = false;
      if (partial && (iteration > 1 || reuse))
        linearize_nodes(x, u, nodes, following, A, B);
      else
        model->linearize(x.topRows(x.rows() - 1), u, following, A, B);
      if (following.allFinite() && A.allFinite() && B.allFinite()) {
        following.rowwise() += offset.transpose();
        for (int attempt = 0; attempt < 12; ++attempt) {
          if (step(x, u, reference, u_ff, following, A, B, mu, active, slack)) { stepped = true; break; }
          mu = std::max(10.0 * mu, 1e-9);
        }
      }
      if (!stepped) {
        result.u = u; result.x = x; result.iterations = iteration;
        return result;
      }
      x.row(1) = (model->step(x0, u.row(0).transpose()) + offset).transpose();
    }
    if (partial) {
      kept_A_ = A;
      kept_B_ = B;
    }
    result.u = u;
    result.x = x;
    result.iterations = iterations;
    result.cost = cost(x, u, reference, u_ff);
    result.finite = x.allFinite() && std::isfinite(result.cost);
    result.active = active;
    result.slack = slack;
    return result;
  }

  // The Riccati recursion's workspace for S states and m torques (sizes fixed at compile time for the arms of 6
  // and 7 joints, `riccati`; Eigen::Dynamic for any other), kept between steps: no allocation once sized.
  // (Aligned storage, on the heap by C++17's aligned new (`riccati`): Eigen's sums over unaligned data start where
  // the data align, so their order, and the last bits of the torques, would follow the solver's address.)
  template <int SS, int MM>
  struct RiccatiWork {
    using MatS = Eigen::Matrix<double, SS, SS>;
    using MatSM = Eigen::Matrix<double, SS, MM>;
    using MatMS = Eigen::Matrix<double, MM, SS>;
    using MatM = Eigen::Matrix<double, MM, MM>;
    using VecS = Eigen::Matrix<double, SS, 1>;
    using VecM = Eigen::Matrix<double, MM, 1>;
    std::vector<MatMS> gains;          // K_k (m, S)
    std::vector<VecM> feedforward;     // k_k (m,)
    MatS P, PA;
    MatSM PB;
    MatM Quu;
    MatMS Qux;
    VecS p, Pcp, e, next_e;
    VecM qu, du;
    Eigen::LLT<MatM> llt;
  };
  std::shared_ptr<RiccatiWork<12, 6>> riccati6_;
  std::shared_ptr<RiccatiWork<14, 7>> riccati7_;
  std::shared_ptr<RiccatiWork<Eigen::Dynamic, Eigen::Dynamic>> riccati_any_;
  VectorXd e_, next_e_;   // (S,) of `linear_states`

  // The unconstrained Gauss-Newton step by the Riccati recursion over the nodes (O(H (S^3 + m^3)); the same
  // minimizer as the condensed Cholesky solve of `rti.RtiSolver._step`, to round-off): with the state deviations
  // e_k+1 = A_k e_k + B_k du_k + c_k (e_0 = 0, c_k the gap F_k - X_k+1) it minimizes
  //   sum_k |X_k+1 + e_k+1 - ref_k+1|^2_W_k + |u_k + du_k - u_ff,k|^2_R + mu |du_k|^2.
  // du (H m,) and the predicted states (H S,); false where a node's Q_uu is not positive definite. One recursion
  // (`riccati_in`), with matrices of sizes fixed at compile time for 6 and 7 joints (its small products unrolled
  // and vectorized; Eigen's general product, meant for large matrices, otherwise).
  bool riccati(const RowMatrixXd& x, const RowMatrixXd& u, const RowMatrixXd& reference, const RowMatrixXd& u_ff,
               const RowMatrixXd& predicted, const RowMatrixXd& A, const RowMatrixXd& B, double mu, VectorXd& du,
               VectorXd& states) {
    if (S() == 12 && m() == 6) return riccati_in(work(riccati6_), x, u, reference, u_ff, predicted, A, B, mu, du, states);
    if (S() == 14 && m() == 7) return riccati_in(work(riccati7_), x, u, reference, u_ff, predicted, A, B, mu, du, states);
    return riccati_in(work(riccati_any_), x, u, reference, u_ff, predicted, A, B, mu, du, states);
  }

  template <typename Work>
  static Work& work(std::shared_ptr<Work>& kept) {
    if (!kept) kept = std::shared_ptr<Work>(new Work());   // (aligned new: Work's alignment is its matrices')
    return *kept;
  }

  template <int SS, int MM>
  bool riccati_in(RiccatiWork<SS, MM>& w, const RowMatrixXd& x, const RowMatrixXd& u, const RowMatrixXd& reference,
                  const RowMatrixXd& u_ff, const RowMatrixXd& predicted, const RowMatrixXd& A, const RowMatrixXd& B,
                  double mu, VectorXd& du, VectorXd& states) {
    const int H = int(u.rows()), s = S(), mm = m();
    w.gains.resize(H);
    w.feedforward.resize(H);
    auto weight = [&](int k) { return k == H - 1 ? terminal_factor : 1.0; };   // of the state at node k + 1
    auto A_k = [&](int k) { return A.template block<SS, SS>(Eigen::Index(k) * s, 0, s, s); };
    auto B_k = [&](int k) { return B.template block<SS, MM>(Eigen::Index(k) * s, 0, s, mm); };
    auto gap = [&](int k) { return (predicted.row(k) - x.row(k + 1)).transpose(); };   // c_k (S,)
    w.P = (weight(H - 1) * Q).asDiagonal();
    w.p = weight(H - 1) * Q.cwiseProduct((x.row(H) - reference.row(H)).transpose());
    for (int k = H - 1; k >= 0; --k) {
      const auto Ak = A_k(k);
      const auto Bk = B_k(k);
      w.Pcp.noalias() = w.P * gap(k);
      w.Pcp += w.p;
      w.PA.noalias() = w.P * Ak;
      w.PB.noalias() = w.P * Bk;
      w.Quu.noalias() = Bk.transpose() * w.PB;
      w.Quu.diagonal() += R + VectorXd::Constant(mm, mu);
      w.Qux.noalias() = Bk.transpose() * w.PA;
      w.qu = R.cwiseProduct((u.row(k) - u_ff.row(k)).transpose());
      w.qu.noalias() += Bk.transpose() * w.Pcp;
      w.llt.compute(w.Quu);
      if (w.llt.info() != Eigen::Success) return false;
      w.gains[k] = -w.Qux;
      w.llt.solveInPlace(w.gains[k]);
      w.feedforward[k] = -w.qu;
      w.llt.solveInPlace(w.feedforward[k]);
      if (k == 0) break;
      w.P.noalias() = Ak.transpose() * w.PA;
      w.P.noalias() += w.Qux.transpose() * w.gains[k];
      w.P = 0.5 * (w.P + w.P.transpose()).eval();
      w.p.noalias() = Ak.transpose() * w.Pcp;
      w.p.noalias() += w.Qux.transpose() * w.feedforward[k];
      w.P.diagonal() += weight(k - 1) * Q;
      w.p += weight(k - 1) * Q.cwiseProduct((x.row(k) - reference.row(k)).transpose());
    }
    du.resize(Eigen::Index(H) * mm);
    states.resize(Eigen::Index(H) * s);
    w.e.setZero(s);
    for (int k = 0; k < H; ++k) {
      w.du = w.feedforward[k];
      w.du.noalias() += w.gains[k] * w.e;
      du.segment(Eigen::Index(k) * mm, mm) = w.du;
      w.next_e.noalias() = A_k(k) * w.e;
      w.next_e.noalias() += B_k(k) * w.du;
      w.next_e += gap(k);
      w.e.swap(w.next_e);
      states.segment(Eigen::Index(k) * s, s) = x.row(k + 1).transpose() + w.e;
    }
    return du.allFinite();
  }

  // the states (H S,) the linearization predicts for the torque steps du (H m,) (e_0 = 0, as `riccati`)
  VectorXd linear_states(const RowMatrixXd& x, const RowMatrixXd& predicted, const RowMatrixXd& A,
                         const RowMatrixXd& B, const VectorXd& du) {
    const int H = int(x.rows()) - 1, s = S(), mm = m();
    VectorXd states(Eigen::Index(H) * s);
    e_ = VectorXd::Zero(s);
    for (int k = 0; k < H; ++k) {
      next_e_.noalias() = A.middleRows(Eigen::Index(k) * s, s) * e_;
      next_e_.noalias() += B.middleRows(Eigen::Index(k) * s, s) * du.segment(Eigen::Index(k) * mm, mm);
      next_e_ += (predicted.row(k) - x.row(k + 1)).transpose();
      e_.swap(next_e_);
      states.segment(Eigen::Index(k) * s, s) = x.row(k + 1).transpose() + e_;
    }
    return states;
  }

  // The condensed problem of the torque steps, for the constrained QP: Gamma (H S, N) block lower triangular,
  // the states at du = 0 (H S,), the Hessian Gamma^T W Gamma + diag(R) + mu (N, N) and the gradient (N,) at
  // du = 0 (the QP's variable is du; `rti.RtiSolver._step`'s condensing); `ScaledHessian` factors it.
  void condense(const RowMatrixXd& x, const RowMatrixXd& u, const RowMatrixXd& reference, const RowMatrixXd& u_ff,
                const RowMatrixXd& predicted, const RowMatrixXd& A, const RowMatrixXd& B, double mu,
                Eigen::MatrixXd& gamma, VectorXd& base, Eigen::MatrixXd& hessian, VectorXd& gradient) const {
    const int H = int(u.rows()), s = S(), mm = m(), N = H * mm;
    gamma = Eigen::MatrixXd::Zero(Eigen::Index(H) * s, N);
    VectorXd drift(Eigen::Index(H) * s);
    for (int k = 0; k < H; ++k) {
      const auto Ak = A.middleRows(Eigen::Index(k) * s, s);
      if (k > 0) {
        gamma.block(Eigen::Index(k) * s, 0, s, Eigen::Index(k) * mm).noalias() =
            Ak * gamma.block(Eigen::Index(k - 1) * s, 0, s, Eigen::Index(k) * mm);
        drift.segment(Eigen::Index(k) * s, s).noalias() = Ak * drift.segment(Eigen::Index(k - 1) * s, s);
      } else {
        drift.segment(0, s).setZero();
      }
      gamma.block(Eigen::Index(k) * s, Eigen::Index(k) * mm, s, mm) = B.middleRows(Eigen::Index(k) * s, s);
      drift.segment(Eigen::Index(k) * s, s) += (predicted.row(k) - x.row(k + 1)).transpose();
    }
    VectorXd state_weight(Eigen::Index(H) * s), effort_weight(N), error(Eigen::Index(H) * s), change(N);
    for (int k = 0; k < H; ++k) {
      const double w = k == H - 1 ? terminal_factor : 1.0;
      state_weight.segment(Eigen::Index(k) * s, s) = w * Q;
      effort_weight.segment(Eigen::Index(k) * mm, mm) = R;
      error.segment(Eigen::Index(k) * s, s) = (x.row(k + 1) - reference.row(k + 1)).transpose();
      change.segment(Eigen::Index(k) * mm, mm) = (u.row(k) - u_ff.row(k)).transpose();
    }
    error += drift;
    hessian = Eigen::MatrixXd::Zero(N, N);
    Eigen::MatrixXd weighted;
    for (int k = 0; k < H; ++k) {     // node by node over Gamma's nonzero columns (lower triangle)
      const int width = (k + 1) * mm;
      const auto block = gamma.block(Eigen::Index(k) * s, 0, s, width);
      weighted = state_weight.segment(Eigen::Index(k) * s, s).asDiagonal() * block;
      hessian.topLeftCorner(width, width).triangularView<Eigen::Lower>() += block.transpose() * weighted;
    }
    hessian.diagonal() += effort_weight + VectorXd::Constant(N, mu);
    hessian.triangularView<Eigen::StrictlyUpper>() = hessian.transpose();
    gradient = gamma.transpose() * state_weight.cwiseProduct(error) + effort_weight.cwiseProduct(change);
    base = Eigen::Map<const VectorXd>(x.data() + s, Eigen::Index(H) * s) + drift;
  }

  // The condensed Hessian and gradient Jacobi-scaled (y = du / scale, scale = diag(hessian)^-1/2) and factored
  // for the dual active-set method: one factorization per control step, whatever rows the QP's rounds take.
  struct ScaledHessian {
    VectorXd scale, y0;
    Eigen::MatrixXd J0;
    bool factor(const Eigen::MatrixXd& hessian, const VectorXd& gradient) {
      scale = hessian.diagonal().cwiseSqrt().cwiseInverse();
      const Eigen::MatrixXd scaled = scale.asDiagonal() * hessian * scale.asDiagonal();
      return DualActiveSet::factor(scaled, gradient.cwiseProduct(scale), J0, y0);
    }
  };

  // one Gauss-Newton step in place; false where the Hessian is not positive definite (u, x untouched)
  bool step(RowMatrixXd& x, RowMatrixXd& u, const RowMatrixXd& reference, const RowMatrixXd& u_ff,
            const RowMatrixXd& predicted, const RowMatrixXd& A, const RowMatrixXd& B, double mu, bool& active,
            double& slack) {
    const int H = int(u.rows()), s = S(), mm = m(), N = H * mm;
    VectorXd du, states;
    if (!riccati(x, u, reference, u_ff, predicted, A, B, mu, du, states)) return false;
    Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 1>> flat_u(u.data(), N);
    VectorXd u_new = flat_u + du;
    bool now_active = false;
    double now_slack = 0.0;
    if (!constrained) {                // mode off: the torques clipped, the states predicted for clipped ones
      bool clipped = false;
      for (int i = 0; i < N; ++i) {
        const double inside_box = std::clamp(u_new[i], -effort_limit[i % mm], effort_limit[i % mm]);
        clipped = clipped || inside_box != u_new[i];
        u_new[i] = inside_box;
      }
      if (clipped) states = linear_states(x, predicted, A, B, u_new - flat_u);
    } else if (inside(u_new, states)) {
      working_rows.clear();
    } else {                           // a limit binds: the condensed QP
      Eigen::MatrixXd gamma, hessian;
      VectorXd base, gradient;
      condense(x, u, reference, u_ff, predicted, A, B, mu, gamma, base, hessian, gradient);
      ScaledHessian scaled;
      if (!scaled.factor(hessian, gradient)) return false;     // not positive definite
      VectorXd lower_step(N), upper_step(N);
      for (int i = 0; i < N; ++i) {
        lower_step[i] = -effort_limit[i % mm] - flat_u[i];
        upper_step[i] = effort_limit[i % mm] - flat_u[i];
      }
      VectorXd delta;
      if (!constrained_step(scaled, lower_step, upper_step, gamma, base, delta, now_active, now_slack))
        return false;
      u_new = flat_u + delta;
      for (int i = 0; i < N; ++i) u_new[i] = std::clamp(u_new[i], -effort_limit[i % mm], effort_limit[i % mm]);
      states = base + gamma * (u_new - flat_u);
    }
    RowMatrixXd x_new(x.rows(), s);
    x_new.row(0) = x.row(0);
    for (int k = 0; k < H; ++k) x_new.row(k + 1) = states.segment(Eigen::Index(k) * s, s).transpose();
    for (int i = 0; i < N; ++i) u(i / mm, i % mm) = u_new[i];
    x = x_new;
    active = now_active;
    slack = now_slack;
    return true;
  }

  bool inside(const VectorXd& u_flat, const VectorXd& states) const {
    const int mm = m(), s = S();
    for (int i = 0; i < u_flat.size(); ++i)
      if (!(std::abs(u_flat[i]) < effort_limit[i % mm])) return false;
    for (int i = 0; i < states.size(); ++i)
      if (!(states[i] < upper[i % s] && states[i] > lower[i % s])) return false;
    return true;
  }

  // the box- and state-constrained step (constraints.CondensedQp.solve); false where no QP can be solved
  bool constrained_step(const ScaledHessian& scaled, const VectorXd& lower_step,
                        const VectorXd& upper_step, const Eigen::MatrixXd& gamma, const VectorXd& base,
                        VectorXd& delta, bool& now_active, double& now_slack) {
    const int s = S(), total = int(base.size());
    std::vector<int> rows;
    for (int row : working_rows) {     // the last working set shifted by one node, the last node's rows kept
      if (row >= total) continue;
      if (row - s >= 0) rows.push_back(row - s);
      if (row >= total - s) rows.push_back(row);
    }
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
    bool soft = !hard;
    int budget = kMaxQpIterations;
    VectorXd states;
    bool settled = false;
    for (int round = 0; round < kMaxRounds; ++round) {
      int status = solve_rows(scaled, lower_step, upper_step, gamma, base, rows, soft, budget, delta,
                              now_slack);
      if (status == 0) {               // the hard rows cannot be met: the soft problem
        soft = true;
        continue;
      }
      if (status < 0) {
        if (rows.empty()) return false;
        break;                         // not settled: the box alone
      }
      states = base + gamma * delta;
      std::vector<int> crossed;
      for (int i = 0; i < total; ++i)
        if ((states[i] > upper[i % s] + kActiveTolerance || states[i] < lower[i % s] - kActiveTolerance) &&
            !std::binary_search(rows.begin(), rows.end(), i))
          crossed.push_back(i);
      if (crossed.empty()) { settled = true; break; }
      std::vector<int> merged;
      std::merge(rows.begin(), rows.end(), crossed.begin(), crossed.end(), std::back_inserter(merged));
      rows = merged;
    }
    if (!settled) {                    // the torque box alone, its crossings reported as slack
      ++unsettled;
      budget = kMaxQpIterations;
      if (solve_rows(scaled, lower_step, upper_step, gamma, base, {}, false, budget, delta, now_slack) < 0)
        return false;
      states = base + gamma * delta;
      now_slack = 0.0;
      for (int i = 0; i < total; ++i) now_slack = std::max(now_slack, violation(states[i], i % s));
      working_rows.clear();
      now_active = true;
      return true;
    }
    working_rows.clear();
    bool near = false;
    for (int i = 0; i < total; ++i)
      if (states[i] > upper[i % s] - kActiveTolerance || states[i] < lower[i % s] + kActiveTolerance) {
        working_rows.push_back(i);
        near = true;
      }
    bool box = false;
    for (int i = 0; i < delta.size(); ++i)
      if (delta[i] >= upper_step[i] - kActiveTolerance || delta[i] <= lower_step[i] + kActiveTolerance) box = true;
    now_active = near || box;
    return true;
  }

  // the QP over [delta, slack of each row] (soft) or delta alone (hard), Jacobi-scaled: 1 solved, 0 the hard rows
  // infeasible, -1 not solved (within the budget). `scaled` is the Hessian's part of the scaled problem (from
  // `ScaledHessian`): the slacks' part is diagonal, so the Hessian is factored once per control step.
  int solve_rows(const ScaledHessian& scaled, const VectorXd& lower_step, const VectorXd& upper_step,
                 const Eigen::MatrixXd& gamma, const VectorXd& base, const std::vector<int>& rows, bool soft,
                 int& budget, VectorXd& delta, double& used_slack) const {
    const int N = int(scaled.scale.size()), chosen = int(rows.size()), s = S();
    const int slacks = soft ? chosen : 0, variables = N + slacks;
    const double weight = 0.5 * penalty_weight;
    // y = scaled variables / scale; the slacks' scale 1 / sqrt(weight): their Hessian 1, their gradient sqrt(weight)
    VectorXd scale(variables);
    scale.head(N) = scaled.scale;
    scale.tail(slacks).setConstant(1.0 / std::sqrt(weight));
    Eigen::MatrixXd J0 = Eigen::MatrixXd::Identity(variables, variables);
    J0.topLeftCorner(N, N) = scaled.J0;
    VectorXd y0(variables);
    y0.head(N) = scaled.y0;
    y0.tail(slacks).setConstant(-std::sqrt(weight));   // (-weight times the slacks' scale)
    // bounds: the torque box on delta, slacks >= 0
    VectorXd lower_bound(variables), upper_bound(variables);
    for (int i = 0; i < N; ++i) {
      lower_bound[i] = lower_step[i] / scale[i];
      upper_bound[i] = upper_step[i] / scale[i];
    }
    lower_bound.tail(slacks).setZero();
    upper_bound.tail(slacks).setConstant(std::numeric_limits<double>::infinity());
    // the rows' two sides, C^T x >= b in the unscaled variables, then scaled: c^T x = (c .* scale)^T y
    int sides = 0;   // (counted as the columns are filled below: a side whose bound is finite)
    for (int j = 0; j < chosen; ++j)
      sides += std::isfinite(lower[rows[j] % s] - base[rows[j]]) + std::isfinite(upper[rows[j] % s] - base[rows[j]]);
    Eigen::MatrixXd C = Eigen::MatrixXd::Zero(variables, sides);
    VectorXd b(sides);
    for (int j = 0, column = 0; j < chosen; ++j) {
      const int row = rows[j];
      const double lo = lower[row % s] - base[row], hi = upper[row % s] - base[row];
      for (int side = 0; side < 2; ++side) {
        const double bound = side == 0 ? lo : -hi;
        if (!std::isfinite(side == 0 ? lo : hi)) continue;
        C.col(column).head(N) = (side == 0 ? 1.0 : -1.0) * gamma.row(row).transpose().cwiseProduct(scale.head(N));
        if (soft) C(N + j, column) = scale[N + j];
        b[column++] = bound;
      }
    }
    VectorXd y;
    int used = 0;
    const auto status = DualActiveSet::solve(J0, y0, lower_bound, upper_bound, C, b, y, std::max(budget, 1), used);
    budget -= used;
    if (status == DualActiveSet::infeasible && !soft && chosen) return 0;
    if (status == DualActiveSet::iteration_limit && !soft && chosen) return 0;
    if (status != DualActiveSet::optimal) return -1;
    VectorXd solution = y.cwiseProduct(scale);
    delta = solution.head(N);
    used_slack = 0.0;
    for (int j = 0; j < slacks; ++j) used_slack = std::max(used_slack, solution[N + j]);
    return 1;
  }
};

// ------------------------------------------------------------------------------------------------------------
// The control step at sample k from the measured state (stdm_drake/closed_loop/policy.py, `MpcStep`, the
// reference): the offset-free disturbance estimate, the real-time iteration warm-started from the last solution
// shifted by one period, and what the step leaves the next one. The gravity fallback (a solution that is not
// finite) is the caller's: its gravity torque comes from the robot's description.

// What a control step leaves the next one (policy.StepMemory): the prediction of the next measured state and the
// disturbance estimate (S,), the warm-start torques (H, m) and nodes (H+1, S; NaN: none).
struct StepMemory {
  VectorXd predicted, disturbance;
  RowMatrixXd plan, nodes;
};

struct ControlStep {
  int horizon = 20;
  double disturbance_gain = 1.0;
  RowMatrixXd reference;      // the reference states (T, S) at the sample period, held past the end
  RowMatrixXd feedforward;    // their gravity torques (T, m)

  // rows first .. first+length-1 of `values`, holding the last past the end
  static RowMatrixXd rows(const RowMatrixXd& values, long first, int length) {
    RowMatrixXd out(length, values.cols());
    for (int i = 0; i < length; ++i) out.row(i) = values.row(std::min<long>(first + i, values.rows() - 1));
    return out;
  }

  // the memory before the first step: no prediction, no disturbance, the reference's gravity torques
  StepMemory first_memory(int state_dim) const {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    return {VectorXd::Constant(state_dim, nan), VectorXd::Zero(state_dim), rows(feedforward, 0, horizon),
            RowMatrixXd::Constant(horizon + 1, state_dim, nan)};
  }

  // One step at sample k from x (S,): true with the solution in `result` and `memory` advanced; false where x or
  // the solution is not finite (the caller's gravity fallback, `fallback_memory`), `estimate` then the
  // disturbance estimate the fallback keeps.
  bool step(RealTimeIteration& rti, long k, const VectorXd& x, StepMemory& memory, StepResult& result,
            VectorXd& estimate) const {
    const int S = rti.S();
    estimate = VectorXd::Zero(S);
    if (!x.allFinite()) return false;
    const RowMatrixXd window = rows(reference, k, horizon + 1);
    const RowMatrixXd u_ff = rows(feedforward, k, horizon);
    if (k > 0 && disturbance_gain > 0) {
      estimate = memory.disturbance + disturbance_gain * (x - memory.predicted);
      if (!estimate.allFinite()) estimate.setZero();
    }
    const RowMatrixXd& warm = k == 0 ? u_ff : memory.plan;
    const bool warm_nodes = k > 0 && memory.nodes.allFinite();
    result = rti.solve(x, warm, window, u_ff, estimate, warm_nodes ? &memory.nodes : nullptr);
    if (!(result.finite && result.u.allFinite())) return false;
    memory.predicted = result.x.row(1).transpose();
    memory.disturbance = estimate;
    memory.plan = rows(result.u, 1, horizon);
    memory.nodes = rows(result.x, 1, horizon + 1);
    return true;
  }

  // the memory after the gravity fallback's torque (m,) at sample k: the model's prediction under it
  StepMemory fallback_memory(const RealTimeIteration& rti, long k, const VectorXd& x, const VectorXd& torque,
                             const VectorXd& estimate) const {
    const int S = rti.S();
    const double nan = std::numeric_limits<double>::quiet_NaN();
    VectorXd predicted = VectorXd::Constant(S, nan);
    if (disturbance_gain > 0) predicted = rti.model->step(x, torque) + estimate;
    return {predicted, estimate, rows(feedforward, k, horizon), RowMatrixXd::Constant(horizon + 1, S, nan)};
  }
};

}  // namespace stdm
