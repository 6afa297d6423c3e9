// step_onnx: steps a model exported by `stdm-drake export` with ONNX Runtime's C API, in a process without
// Python: what a C++ controller (ros2_control, a UR RTDE client, a Drake C++ diagram) does every control cycle.
//
//   step_onnx MODEL.onnx rows IN.f32 OUT.f32      every row of IN (the graph's inputs in order: state (2n),
//                                                 action (m)[, features (k)]) one call at batch 1; OUT: next_state
//   step_onnx MODEL.onnx rollout IN.f32 OUT.f32 T IN: x_0 (2n) then T actions (m each); each next_state is fed
//                                                 back as the next call's state; OUT: x_1 .. x_T
//   step_onnx MODEL.onnx bench IN.f32 CALLS       CALLS calls at batch 1 on IN's first row (after 200 warm-up
//                                                 calls); prints "median_us min_us p99_us" per call
//
// Files are raw little-endian float32. Exit status 2 with one line on stderr for any error.
// Build (tools/cpp/build.sh): g++ -O2 -std=c++17 step_onnx.cpp -I ONNXRUNTIME_INCLUDE -L DIR -lonnxruntime
#include <onnxruntime_c_api.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

namespace {

const OrtApi* api = nullptr;

[[noreturn]] void Fail(const std::string& message) {
  std::fprintf(stderr, "step_onnx: error: %s\n", message.c_str());
  std::exit(2);
}

void Check(OrtStatus* status) {
  if (status != nullptr) {
    std::string message = api->GetErrorMessage(status);
    api->ReleaseStatus(status);
    Fail(message);
  }
}

std::vector<float> ReadFloats(const std::string& path) {
  std::ifstream file(path, std::ios::binary | std::ios::ate);
  if (!file) Fail("cannot read " + path);
  const std::streamsize bytes = file.tellg();
  if (bytes % sizeof(float) != 0) Fail(path + " is not a float32 file");
  std::vector<float> values(bytes / sizeof(float));
  file.seekg(0);
  file.read(reinterpret_cast<char*>(values.data()), bytes);
  return values;
}

void WriteFloats(const std::string& path, const std::vector<float>& values) {
  std::ofstream file(path, std::ios::binary);
  file.write(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float));
  if (!file) Fail("cannot write " + path);
}

// One session at batch 1: input tensors over fixed buffers, the next_state output over its own buffer, so a
// call is one Run and no allocation, as in a real-time loop.
class Stepper {
 public:
  explicit Stepper(const char* model_path) {
    Check(api->CreateEnv(ORT_LOGGING_LEVEL_WARNING, "step_onnx", &env_));
    OrtSessionOptions* options = nullptr;
    Check(api->CreateSessionOptions(&options));
    Check(api->SetIntraOpNumThreads(options, 1));
    Check(api->SetInterOpNumThreads(options, 1));
    Check(api->SetSessionExecutionMode(options, ORT_SEQUENTIAL));
    Check(api->SetSessionGraphOptimizationLevel(options, ORT_ENABLE_ALL));
    Check(api->CreateSession(env_, model_path, options, &session_));
    api->ReleaseSessionOptions(options);
    Check(api->CreateCpuMemoryInfo(OrtArenaAllocator, OrtMemTypeDefault, &memory_));
    OrtAllocator* allocator = nullptr;
    Check(api->GetAllocatorWithDefaultOptions(&allocator));
    size_t count = 0;
    Check(api->SessionGetInputCount(session_, &count));
    for (size_t i = 0; i < count; ++i) {
      char* name = nullptr;
      Check(api->SessionGetInputName(session_, i, allocator, &name));
      input_names_.emplace_back(name);
      Check(api->AllocatorFree(allocator, name));
      widths_.push_back(InputWidth(i));
    }
    for (size_t i = 0; i < count; ++i) {
      offsets_.push_back(row_width_);
      row_width_ += widths_[i];
    }
    if (input_names_.size() < 2 || input_names_[0] != "state") Fail("not a model of `stdm-drake export`");
    state_width_ = widths_[0];
    row_.assign(row_width_, 0.0f);
    next_.assign(state_width_, 0.0f);
    for (size_t i = 0; i < count; ++i) {
      int64_t shape[2] = {1, widths_[i]};
      OrtValue* value = nullptr;
      Check(api->CreateTensorWithDataAsOrtValue(memory_, row_.data() + offsets_[i], widths_[i] * sizeof(float), shape,
                                                2, ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT, &value));
      inputs_.push_back(value);
      input_pointers_.push_back(input_names_[i].c_str());
    }
    int64_t shape[2] = {1, state_width_};
    Check(api->CreateTensorWithDataAsOrtValue(memory_, next_.data(), next_.size() * sizeof(float), shape, 2,
                                              ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT, &output_));
  }

  ~Stepper() {
    for (OrtValue* value : inputs_) api->ReleaseValue(value);
    api->ReleaseValue(output_);
    api->ReleaseMemoryInfo(memory_);
    api->ReleaseSession(session_);
    api->ReleaseEnv(env_);
  }

  size_t row_width() const { return row_width_; }
  size_t state_width() const { return static_cast<size_t>(state_width_); }
  size_t action_width() const { return static_cast<size_t>(widths_[1]); }
  size_t input_count() const { return input_names_.size(); }
  float* row() { return row_.data(); }
  const std::vector<float>& next() const { return next_; }

  // next_state for the inputs in row(); batch 1.
  void Step() {
    const char* output_name = "next_state";
    Check(api->Run(session_, nullptr, input_pointers_.data(), inputs_.data(), inputs_.size(), &output_name, 1,
                   &output_));
  }

 private:
  int64_t InputWidth(size_t index) {
    OrtTypeInfo* type = nullptr;
    Check(api->SessionGetInputTypeInfo(session_, index, &type));
    const OrtTensorTypeAndShapeInfo* tensor = nullptr;
    Check(api->CastTypeInfoToTensorInfo(type, &tensor));
    size_t rank = 0;
    Check(api->GetDimensionsCount(tensor, &rank));
    std::vector<int64_t> dims(rank);
    Check(api->GetDimensions(tensor, dims.data(), rank));
    api->ReleaseTypeInfo(type);
    if (rank != 2 || dims[1] < 0) Fail("an input is not (batch, width)");
    return dims[1];
  }

  OrtEnv* env_ = nullptr;
  OrtSession* session_ = nullptr;
  OrtMemoryInfo* memory_ = nullptr;
  std::vector<std::string> input_names_;
  std::vector<const char*> input_pointers_;
  std::vector<int64_t> widths_, offsets_;
  int64_t row_width_ = 0, state_width_ = 0;
  std::vector<float> row_, next_;
  std::vector<OrtValue*> inputs_;
  OrtValue* output_ = nullptr;
};

}  // namespace

int main(int argc, char** argv) {
  api = OrtGetApiBase()->GetApi(ORT_API_VERSION);
  if (api == nullptr) Fail("this ONNX Runtime library is older than the headers (API " + std::to_string(ORT_API_VERSION) + ")");
  if (argc < 5) Fail("usage: step_onnx MODEL.onnx rows|rollout|bench IN.f32 OUT.f32|CALLS [T]");
  const std::string mode = argv[2];
  Stepper stepper(argv[1]);
  const std::vector<float> in = ReadFloats(argv[3]);
  const size_t width = stepper.row_width(), state = stepper.state_width();
  if (mode == "rows") {
    if (in.empty() || in.size() % width != 0) Fail("rows: the input is not whole rows of " + std::to_string(width));
    std::vector<float> out;
    for (size_t start = 0; start < in.size(); start += width) {
      std::copy(in.begin() + start, in.begin() + start + width, stepper.row());
      stepper.Step();
      out.insert(out.end(), stepper.next().begin(), stepper.next().end());
    }
    WriteFloats(argv[4], out);
  } else if (mode == "rollout") {
    if (argc < 6) Fail("rollout needs T");
    const size_t steps = std::strtoul(argv[5], nullptr, 10), action = stepper.action_width();
    if (stepper.input_count() != 2) Fail("rollout: the model takes feature inputs; compute them and use rows");
    if (in.size() != state + steps * action) Fail("rollout: the input is not x_0 and T actions");
    std::copy(in.begin(), in.begin() + state, stepper.row());
    std::vector<float> out;
    for (size_t k = 0; k < steps; ++k) {
      std::copy(in.begin() + state + k * action, in.begin() + state + (k + 1) * action, stepper.row() + state);
      stepper.Step();
      out.insert(out.end(), stepper.next().begin(), stepper.next().end());
      std::copy(stepper.next().begin(), stepper.next().end(), stepper.row());
    }
    WriteFloats(argv[4], out);
  } else if (mode == "bench") {
    const long calls = std::strtol(argv[4], nullptr, 10);
    if (in.size() < width || calls < 1) Fail("bench: needs one input row and CALLS >= 1");
    std::copy(in.begin(), in.begin() + width, stepper.row());
    for (int i = 0; i < 200; ++i) stepper.Step();
    std::vector<double> micros(calls);
    for (long i = 0; i < calls; ++i) {
      const auto start = std::chrono::steady_clock::now();
      stepper.Step();
      micros[i] = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - start).count();
    }
    std::sort(micros.begin(), micros.end());
    std::printf("%.3f %.3f %.3f\n", micros[calls / 2], micros[0], micros[std::min(calls - 1, calls * 99 / 100)]);
  } else {
    Fail("unknown mode " + mode + " (rows, rollout, bench)");
  }
  return 0;
}
