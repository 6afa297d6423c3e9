// step_onnx: steps a model exported by `stdm-drake export` with ONNX Runtime's C API, in a process without
// Python: what a C++ controller (ros2_control, a UR RTDE client, a Drake C++ diagram) does every control cycle.
//
//   step_onnx MODEL.onnx rows IN.f32 OUT.f32 [NAMES]  every row of IN (the graph's inputs in order: state (2n),
//                                                 action (m)[, features (k)]) one call at batch 1; OUT: the outputs
//                                                 NAMES (comma-separated, default next_state) of each row, in turn
//   step_onnx MODEL.onnx rollout IN.f32 OUT.f32 T IN: x_0 (2n) then T actions (m each); each next_state is fed
//                                                 back as the next call's state; OUT: x_1 .. x_T
//   step_onnx MODEL.onnx bench IN.f32 CALLS       CALLS calls at batch 1 on IN's first row (after 200 warm-up
//                                                 calls); prints "median M us, min M us, p99 M us per call (CALLS calls at batch 1)"
//   (rows of MODEL.jacobian.onnx with NAMES next_state,jacobian_state,jacobian_action: a C++ MPC's A and B)
//
// Files and streams are raw little-endian float32. Exit status 2 with one line on stderr for any error. A
// controller keeps the Stepper class: it owns its ONNX Runtime objects (not copyable), and Step() throws
// std::runtime_error on an error.
//
// Build (tools/cpp/build.sh): g++ -O2 -std=c++17 step_onnx.cpp -I ONNXRUNTIME_INCLUDE -L DIR -lonnxruntime
#include <onnxruntime_c_api.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

const OrtApi* api = nullptr;

// An ONNX Runtime status as an exception (the status released first).
void Check(OrtStatus* status) {
  if (status != nullptr) {
    std::string message = api->GetErrorMessage(status);
    api->ReleaseStatus(status);
    throw std::runtime_error(message);
  }
}

// Owners of ONNX Runtime objects: each released by its own Release function, on every path.
struct Release {
  void operator()(OrtEnv* p) const { api->ReleaseEnv(p); }
  void operator()(OrtSession* p) const { api->ReleaseSession(p); }
  void operator()(OrtSessionOptions* p) const { api->ReleaseSessionOptions(p); }
  void operator()(OrtMemoryInfo* p) const { api->ReleaseMemoryInfo(p); }
  void operator()(OrtTypeInfo* p) const { api->ReleaseTypeInfo(p); }
  void operator()(OrtValue* p) const { api->ReleaseValue(p); }
};
template <typename T>
using Owned = std::unique_ptr<T, Release>;

std::vector<float> ReadFloats(const std::string& path) {
  std::ifstream file(path, std::ios::binary | std::ios::ate);
  if (!file) throw std::runtime_error("cannot read " + path);
  const std::streamsize bytes = file.tellg();
  if (bytes < 0 || bytes % sizeof(float) != 0) throw std::runtime_error(path + " is not a float32 file");
  std::vector<float> values(bytes / sizeof(float));
  file.seekg(0);
  if (!file.read(reinterpret_cast<char*>(values.data()), bytes)) throw std::runtime_error("cannot read " + path);
  return values;
}

void WriteFloats(const std::string& path, const std::vector<float>& values) {
  std::ofstream file(path, std::ios::binary);
  file.write(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float));
  file.close();   // (the flush: a full disk shows here)
  if (!file) throw std::runtime_error("cannot write " + path);
}

// A whole decimal count in [1, limit] (no sign, no trailing characters), or an error naming `what`.
size_t Count(const char* text, const char* what, size_t limit) {
  char* end = nullptr;
  const unsigned long long value = std::strtoull(text, &end, 10);
  if (text[0] < '0' || text[0] > '9' || *end != '\0' || value < 1 || value > limit) {
    throw std::runtime_error(std::string(what) + " must be a whole number in 1.." + std::to_string(limit) +
                             ", got " + text);
  }
  return static_cast<size_t>(value);
}

// One session at batch 1: input tensors over fixed buffers, each asked-for output over its own buffer, so a call
// is one Run and no allocation of the program's own, as in a real-time loop.
class Stepper {
 public:
  explicit Stepper(const char* model_path, std::vector<std::string> output_names = {"next_state"})
      : output_names_(std::move(output_names)) {
    OrtEnv* env = nullptr;
    Check(api->CreateEnv(ORT_LOGGING_LEVEL_WARNING, "step_onnx", &env));
    env_.reset(env);
    OrtSessionOptions* raw_options = nullptr;
    Check(api->CreateSessionOptions(&raw_options));
    Owned<OrtSessionOptions> options(raw_options);
    Check(api->SetIntraOpNumThreads(raw_options, 1));
    Check(api->SetInterOpNumThreads(raw_options, 1));
    Check(api->SetSessionExecutionMode(raw_options, ORT_SEQUENTIAL));
    Check(api->SetSessionGraphOptimizationLevel(raw_options, ORT_ENABLE_ALL));
    OrtSession* session = nullptr;
    Check(api->CreateSession(env, model_path, raw_options, &session));
    session_.reset(session);
    OrtMemoryInfo* memory = nullptr;
    Check(api->CreateCpuMemoryInfo(OrtArenaAllocator, OrtMemTypeDefault, &memory));
    memory_.reset(memory);
    OrtAllocator* allocator = nullptr;
    Check(api->GetAllocatorWithDefaultOptions(&allocator));
    size_t count = 0;
    Check(api->SessionGetInputCount(session, &count));
    for (size_t i = 0; i < count; ++i) {
      char* name = nullptr;
      Check(api->SessionGetInputName(session, i, allocator, &name));
      input_names_.emplace_back(name);
      Check(api->AllocatorFree(allocator, name));
      widths_.push_back(InputWidth(i));
      offsets_.push_back(row_width_);
      row_width_ += widths_.back();
    }
    if (input_names_.size() < 2 || input_names_[0] != "state") {
      throw std::runtime_error(std::string(model_path) + " is not a model of `stdm-drake export`");
    }
    state_width_ = widths_[0];
    row_.assign(row_width_, 0.0f);
    for (size_t i = 0; i < count; ++i) {
      inputs_.push_back(Tensor(row_.data() + offsets_[i], {1, widths_[i]}));
      input_values_.push_back(inputs_.back().get());
      input_pointers_.push_back(input_names_[i].c_str());
    }
    outputs_.resize(output_names_.size());                     // (sized first: the tensors point into them)
    for (size_t i = 0; i < output_names_.size(); ++i) {
      std::vector<int64_t> shape = OutputShape(output_names_[i]);
      size_t size = 1;
      for (int64_t dim : shape) size *= static_cast<size_t>(dim);
      outputs_[i].assign(size, 0.0f);
      output_tensors_.push_back(Tensor(outputs_[i].data(), shape));
      output_values_.push_back(output_tensors_.back().get());
      output_pointers_.push_back(output_names_[i].c_str());
    }
  }

  Stepper(const Stepper&) = delete;             // (it owns the session and the tensors over its buffers)
  Stepper& operator=(const Stepper&) = delete;

  size_t row_width() const { return static_cast<size_t>(row_width_); }
  size_t state_width() const { return static_cast<size_t>(state_width_); }
  size_t action_width() const { return static_cast<size_t>(widths_[1]); }
  size_t input_count() const { return input_names_.size(); }
  float* row() { return row_.data(); }

  // The i-th asked-for output (the first: next_state unless asked otherwise), row-major, batch 1.
  const std::vector<float>& output(size_t i = 0) const { return outputs_.at(i); }
  const std::vector<float>& next() const { return outputs_[0]; }

  // The outputs for the inputs in row(), batch 1; std::runtime_error on an ONNX Runtime error.
  void Step() {
    Check(api->Run(session_.get(), nullptr, input_pointers_.data(), input_values_.data(), input_values_.size(),
                   output_pointers_.data(), output_values_.size(), output_values_.data()));
  }

 private:
  // A float32 tensor of `shape` over `data` (the caller's buffer: no copy per call).
  Owned<OrtValue> Tensor(float* data, const std::vector<int64_t>& shape) {
    size_t size = 1;
    for (int64_t dim : shape) size *= static_cast<size_t>(dim);
    OrtValue* value = nullptr;
    Check(api->CreateTensorWithDataAsOrtValue(memory_.get(), data, size * sizeof(float), shape.data(), shape.size(),
                                              ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT, &value));
    return Owned<OrtValue>(value);
  }

  // The shape of output `name` at batch 1 (its symbolic batch axis, and a member axis E, as declared).
  std::vector<int64_t> OutputShape(const std::string& name) {
    size_t count = 0;
    Check(api->SessionGetOutputCount(session_.get(), &count));
    OrtAllocator* allocator = nullptr;
    Check(api->GetAllocatorWithDefaultOptions(&allocator));
    for (size_t i = 0; i < count; ++i) {
      char* found = nullptr;
      Check(api->SessionGetOutputName(session_.get(), i, allocator, &found));
      const bool same = name == found;
      Check(api->AllocatorFree(allocator, found));
      if (!same) continue;
      OrtTypeInfo* type = nullptr;
      Check(api->SessionGetOutputTypeInfo(session_.get(), i, &type));
      std::vector<int64_t> dims = Dimensions(type);
      for (int64_t& dim : dims) dim = dim < 0 ? 1 : dim;     // (the batch axis: one row)
      return dims;
    }
    throw std::runtime_error("the model has no output " + name);
  }

  int64_t InputWidth(size_t index) {
    OrtTypeInfo* type = nullptr;
    Check(api->SessionGetInputTypeInfo(session_.get(), index, &type));
    const std::vector<int64_t> dims = Dimensions(type);
    if (dims.size() != 2 || dims[1] < 1) throw std::runtime_error("an input is not (batch, width)");
    return dims[1];
  }

  // The declared dimensions of a tensor's type (-1 for a symbolic one, the batch); the type is released.
  static std::vector<int64_t> Dimensions(OrtTypeInfo* raw_type) {
    Owned<OrtTypeInfo> type(raw_type);
    const OrtTensorTypeAndShapeInfo* tensor = nullptr;
    Check(api->CastTypeInfoToTensorInfo(raw_type, &tensor));
    size_t rank = 0;
    Check(api->GetDimensionsCount(tensor, &rank));
    std::vector<int64_t> dims(rank);
    Check(api->GetDimensions(tensor, dims.data(), rank));
    return dims;
  }

  // (declared in release order reversed: tensors before memory info, session before environment)
  Owned<OrtEnv> env_;
  Owned<OrtSession> session_;
  Owned<OrtMemoryInfo> memory_;
  std::vector<std::string> input_names_;
  std::vector<const char*> input_pointers_;
  std::vector<int64_t> widths_, offsets_;
  int64_t row_width_ = 0, state_width_ = 0;
  std::vector<float> row_;
  std::vector<Owned<OrtValue>> inputs_;
  std::vector<const OrtValue*> input_values_;
  std::vector<std::string> output_names_;
  std::vector<const char*> output_pointers_;
  std::vector<std::vector<float>> outputs_;
  std::vector<Owned<OrtValue>> output_tensors_;
  std::vector<OrtValue*> output_values_;
};


std::vector<std::string> Names(const std::string& text) {
  std::vector<std::string> names;
  size_t start = 0;
  for (size_t comma; (comma = text.find(',', start)) != std::string::npos; start = comma + 1) {
    names.push_back(text.substr(start, comma - start));
  }
  names.push_back(text.substr(start));
  return names;
}

int Run(int argc, char** argv) {
  if (argc < 5) throw std::runtime_error("usage: step_onnx MODEL.onnx rows|rollout|bench IN.f32 OUT.f32|CALLS [T|NAMES]");
  const std::string mode = argv[2];
  if (mode != "rows" && mode != "rollout" && mode != "bench") {
    throw std::runtime_error("unknown mode " + mode + " (rows, rollout, bench)");
  }
  Stepper stepper(argv[1], mode == "rows" && argc > 5 ? Names(argv[5]) : std::vector<std::string>{"next_state"});
  const std::vector<float> in = ReadFloats(argv[3]);
  const size_t width = stepper.row_width(), state = stepper.state_width();
  std::vector<float> out;
  if (mode == "rows") {
    if (in.empty() || in.size() % width != 0) {
      throw std::runtime_error("rows: the input is not whole rows of " + std::to_string(width));
    }
    const size_t outputs = argc > 5 ? Names(argv[5]).size() : 1;
    for (size_t start = 0; start < in.size(); start += width) {
      std::copy(in.begin() + start, in.begin() + start + width, stepper.row());
      stepper.Step();
      for (size_t i = 0; i < outputs; ++i) {
        out.insert(out.end(), stepper.output(i).begin(), stepper.output(i).end());
      }
    }
    WriteFloats(argv[4], out);
  } else if (mode == "rollout") {
    if (argc < 6) throw std::runtime_error("rollout needs T");
    if (stepper.input_count() != 2) throw std::runtime_error("rollout: the model takes feature inputs; use rows");
    const size_t action = stepper.action_width();
    const size_t steps = Count(argv[5], "T", (in.size() - std::min(in.size(), state)) / action);
    if (in.size() != state + steps * action) throw std::runtime_error("rollout: the input is not x_0 and T actions");
    std::copy(in.begin(), in.begin() + state, stepper.row());
    for (size_t k = 0; k < steps; ++k) {
      std::copy(in.begin() + state + k * action, in.begin() + state + (k + 1) * action, stepper.row() + state);
      stepper.Step();
      out.insert(out.end(), stepper.next().begin(), stepper.next().end());
      std::copy(stepper.next().begin(), stepper.next().end(), stepper.row());
    }
    WriteFloats(argv[4], out);
  } else {
    const size_t calls = Count(argv[4], "CALLS", 100000000);
    if (in.size() < width) throw std::runtime_error("bench: needs one input row");
    std::copy(in.begin(), in.begin() + width, stepper.row());
    for (int i = 0; i < 200; ++i) stepper.Step();
    std::vector<double> micros(calls);
    for (size_t i = 0; i < calls; ++i) {
      const auto start = std::chrono::steady_clock::now();
      stepper.Step();
      micros[i] = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - start).count();
    }
    std::sort(micros.begin(), micros.end());
    std::printf("median %.3f us, min %.3f us, p99 %.3f us per call (%zu calls at batch 1)\n", micros[calls / 2], micros[0],
                micros[std::min(calls - 1, calls * 99 / 100)], calls);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  api = OrtGetApiBase()->GetApi(ORT_API_VERSION);
  if (api == nullptr) {
    std::fprintf(stderr, "step_onnx: error: this ONNX Runtime library is older than the headers (API %d)\n",
                 ORT_API_VERSION);
    return 2;
  }
  try {
    return Run(argc, argv);
  } catch (const std::exception& error) {     // (ONNX Runtime's errors, bad files and counts, memory)
    std::fprintf(stderr, "step_onnx: error: %s\n", error.what());
    return 2;
  }
}
