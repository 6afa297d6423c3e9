// The robot's rigid-body dynamics for the compiled core (control_step.hpp), declared apart from the code that
// uses it so that the one translation unit that includes Pinocchio (rigid_body.cpp) depends on this header only.
#pragma once

#include <memory>
#include <vector>

#include <Eigen/Core>

namespace stdm {

using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using RowMatrixXf = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using Eigen::VectorXd;

// The robot's continuous rigid-body dynamics: q'' = M(q)^-1 (B tau + tau_g(q) - C(q, v) v - D v + tau_c(v)),
// tau_c = -F_c tanh(v / v_s), in Drake's joint order (Pinocchio's may differ: `to_pin`).

struct RigidBody {
  int joints = 0, actuators = 0;
  std::vector<int> to_pin;        // q_pin[i] = q_drake[to_pin[i]]
  VectorXd damping;               // D (n,) N m s/rad, Drake order
  VectorXd friction, friction_scale;   // F_c (n,) N m, v_s (n,) rad/s; empty: none
  RowMatrixXd actuation;          // B (n, m)

  // joints: per Pinocchio joint 1..n, its parent (0: the world), kind (0 revolute about z, 1 prismatic along z),
  // placement (rotation (3, 3) row-major, translation (3,)), and the inertia of its bodies (mass kg, centre of
  // mass (3,) m, rotational inertia about the centre of mass (3, 3) kg m^2), in its own frame; armature (n,)
  // kg m^2 in Pinocchio's order; gravity (3,) m/s^2. (rigid_body.cpp: the only code that sees Pinocchio.)
  void build(const std::vector<int>& parents, const std::vector<int>& kinds, const RowMatrixXd& rotations,
             const RowMatrixXd& translations, const VectorXd& masses, const RowMatrixXd& centers,
             const RowMatrixXd& inertias, const VectorXd& armature, const VectorXd& gravity);

  // the generalized force B tau - D v + tau_c(v) (n,), Drake order, into out (sized once, then no allocation)
  void force(const Eigen::Ref<const VectorXd>& v, const Eigen::Ref<const VectorXd>& tau, VectorXd& out) const {
    out.noalias() = actuation * tau;
    out -= damping.cwiseProduct(v);
    if (friction.size()) out -= friction.cwiseProduct((v.array() / friction_scale.array()).tanh().matrix());
  }

  // q'' (n,) rad/s^2
  VectorXd acceleration(const VectorXd& q, const VectorXd& v, const VectorXd& tau) const;
  // the same into out (n,), with no allocation (the RK4 stages of the plant model's predictions)
  void acceleration(const Eigen::Ref<const VectorXd>& q, const Eigen::Ref<const VectorXd>& v,
                    const Eigen::Ref<const VectorXd>& tau, Eigen::Ref<VectorXd> out) const;
  // the torque (n,) N m on every joint that holds the arm still at q (n,) rad: -tau_g(q)
  VectorXd gravity_torque(const VectorXd& q) const;
  // q'' (n,) and d q'' / d(q, v, tau) (n, 2n + m)
  void acceleration_and_jacobian(const VectorXd& q, const VectorXd& v, const VectorXd& tau, VectorXd& out,
                                 RowMatrixXd& jacobian) const;

 private:
  struct Pinocchio;                          // the Pinocchio model and its workspace (rigid_body.cpp)
  std::shared_ptr<Pinocchio> pinocchio_;
};

}  // namespace stdm
