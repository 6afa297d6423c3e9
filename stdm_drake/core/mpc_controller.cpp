// mpc_controller: the MPC of a controller file (`stdm-drake export --target controller`) as a program.
//
//   mpc_controller CONTROLLER_FILE PLAN_FILE
//
// PLAN_FILE: the reference, one state [q (n) rad, v (n) rad/s] per line at the controller's sample period.
// Then, every period, one measured state per line on standard input (2n numbers) -> one torque per line on
// standard output (m numbers, N m), until the input ends. Errors: one line on standard error, exit status 2.
// Build: stdm_drake.closed_loop.compiled.build_controller_program (docs/guides/deploy.md).
#include <iostream>

#include "controller.hpp"

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: mpc_controller CONTROLLER_FILE PLAN_FILE\n");
    return 2;
  }
  try {
    stdm::Controller controller = stdm::Controller::load(argv[1]);
    const int S = controller.rti.S();
    std::ifstream plan_file(argv[2]);
    if (!plan_file) throw std::runtime_error(std::string("cannot open ") + argv[2]);
    std::vector<double> values;
    for (double value; plan_file >> value;) values.push_back(value);
    if (values.empty() || values.size() % S != 0)
      throw std::runtime_error(std::string(argv[2]) + ": expected rows of " + std::to_string(S) + " numbers");
    controller.start(Eigen::Map<stdm::RowMatrixXd>(values.data(), long(values.size() / S), S));
    Eigen::VectorXd x(S);
    std::string line;
    while (std::getline(std::cin, line)) {
      std::istringstream words(line);
      for (int i = 0; i < S; ++i)
        if (!(words >> x[i])) throw std::runtime_error("a state line needs " + std::to_string(S) + " numbers");
      const Eigen::VectorXd torque = controller.step(x);
      for (int j = 0; j < torque.size(); ++j) std::printf(j ? " %.17g" : "%.17g", torque[j]);
      std::printf("\n");
      std::fflush(stdout);
    }
  } catch (const std::exception& error) {
    std::fprintf(stderr, "mpc_controller: %s\n", error.what());
    return 2;
  }
  return 0;
}
