// The rigid-body dynamics of control_step.hpp on Pinocchio, the one translation unit that includes it: header-only in
// the extension (compiled for the installing CPU, setup.py), libpinocchio_default's precompiled algorithms in the
// controller program (closed_loop/compiled.py builds it for generic x86-64).
#include <pinocchio/algorithm/aba-derivatives.hpp>
#include <pinocchio/algorithm/aba.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <pinocchio/multibody.hpp>

#include "rigid_body.hpp"

namespace stdm {

struct RigidBody::Pinocchio {
  pinocchio::Model model;
  std::unique_ptr<pinocchio::Data> data;    // made once the model is complete
  Eigen::VectorXd q, v, f;                  // Pinocchio's order
  Eigen::VectorXd force;                    // Drake's order
};

void RigidBody::build(const std::vector<int>& parents, const std::vector<int>& kinds, const RowMatrixXd& rotations,
                      const RowMatrixXd& translations, const VectorXd& masses, const RowMatrixXd& centers,
                      const RowMatrixXd& inertias, const VectorXd& armature, const VectorXd& gravity) {
  pinocchio_ = std::make_shared<Pinocchio>();
  pinocchio::Model& model = pinocchio_->model;
  model.gravity.linear(gravity.head<3>());
  model.gravity.angular().setZero();
  for (size_t i = 0; i < parents.size(); ++i) {
    Eigen::Matrix3d rotation = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(rotations.row(i).data());
    pinocchio::SE3 placement(rotation, translations.row(i).transpose());
    const std::string name = "joint" + std::to_string(i + 1);
    const pinocchio::JointIndex id =
        kinds[i] == 0 ? model.addJoint(parents[i], pinocchio::JointModelRZ(), placement, name)
                      : model.addJoint(parents[i], pinocchio::JointModelPZ(), placement, name);
    Eigen::Matrix3d inertia = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(inertias.row(i).data());
    model.appendBodyToJoint(id, pinocchio::Inertia(masses[i], centers.row(i).transpose(), inertia));
  }
  model.armature = armature;
  pinocchio_->data = std::make_unique<pinocchio::Data>(model);
  pinocchio_->q.resize(model.nv);
  pinocchio_->v.resize(model.nv);
  pinocchio_->f.resize(model.nv);
  pinocchio_->force.resize(model.nv);
}

VectorXd RigidBody::acceleration(const VectorXd& q, const VectorXd& v, const VectorXd& tau) const {
  VectorXd out(joints);
  acceleration(q, v, tau, out);
  return out;
}

void RigidBody::acceleration(const Eigen::Ref<const VectorXd>& q, const Eigen::Ref<const VectorXd>& v,
                             const Eigen::Ref<const VectorXd>& tau, Eigen::Ref<VectorXd> out) const {
  Pinocchio& p = *pinocchio_;
  VectorXd& force_drake = p.force;
  force(v, tau, force_drake);
  for (int i = 0; i < joints; ++i) {
    p.q[i] = q[to_pin[i]];
    p.v[i] = v[to_pin[i]];
    p.f[i] = force_drake[to_pin[i]];
  }
  // (the world convention: the same accelerations as the default local one, to round-off, in fewer operations on
  // these chains: about 5 % of the plant model's control step in a replay of recorded steps. The arguments as
  // Eigen::Ref, the types libpinocchio_default instantiates: the controller program links that instance instead of
  // compiling its own, 74 -> 10 s of this file's build)
  using ConstRef = Eigen::Ref<const Eigen::VectorXd>;
  pinocchio::aba(p.model, *p.data, ConstRef(p.q), ConstRef(p.v), ConstRef(p.f), pinocchio::Convention::WORLD);
  for (int i = 0; i < joints; ++i) out[to_pin[i]] = p.data->ddq[i];
}

VectorXd RigidBody::gravity_torque(const VectorXd& q) const {
  Pinocchio& p = *pinocchio_;
  for (int i = 0; i < joints; ++i) p.q[i] = q[to_pin[i]];
  pinocchio::computeGeneralizedGravity(p.model, *p.data, p.q);
  VectorXd out(joints);
  for (int i = 0; i < joints; ++i) out[to_pin[i]] = p.data->g[i];
  return out;
}

void RigidBody::acceleration_and_jacobian(const VectorXd& q, const VectorXd& v, const VectorXd& tau, VectorXd& out,
                                          RowMatrixXd& jacobian) const {
  Pinocchio& p = *pinocchio_;
  pinocchio::Data& data = *p.data;
  const int n = joints;
  VectorXd force_drake;
  force(v, tau, force_drake);
  for (int i = 0; i < n; ++i) {
    p.q[i] = q[to_pin[i]];
    p.v[i] = v[to_pin[i]];
    p.f[i] = force_drake[to_pin[i]];
  }
  pinocchio::computeABADerivatives(p.model, data, p.q, p.v, p.f);
  data.Minv.triangularView<Eigen::StrictlyLower>() = data.Minv.transpose();
  out.resize(n);
  jacobian.resize(n, 2 * n + actuators);
  RowMatrixXd inverse(n, n);
  for (int i = 0; i < n; ++i) {
    out[to_pin[i]] = data.ddq[i];
    for (int j = 0; j < n; ++j) {
      jacobian(to_pin[i], to_pin[j]) = data.ddq_dq(i, j);
      jacobian(to_pin[i], n + to_pin[j]) = data.ddq_dv(i, j);
      inverse(to_pin[i], to_pin[j]) = data.Minv(i, j);
    }
  }
  // the extra forces' own slope d(-D v + tau_c) / dv (diagonal), through M^-1
  for (int j = 0; j < n; ++j) {
    double slope = -damping[j];
    if (friction.size()) {
      const double c = std::cosh(v[j] / friction_scale[j]);
      slope -= friction[j] / friction_scale[j] / (c * c);
    }
    if (slope != 0.0) jacobian.col(n + j) += slope * inverse.col(j);
  }
  jacobian.rightCols(actuators).noalias() = inverse * actuation;
}

}  // namespace stdm
