// libFuzzer target for core/camera.h loadCameraYaml (our camera YAML and ROS camera_info YAML).
// A camera that loads must survive the round trip saveCameraYaml -> loadCameraYaml unchanged, and
// projecting / unprojecting its image corners must not trip the sanitizers.
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include <Eigen/Core>

#include "fuzz_common.h"
#include "nerfslam/core/camera.h"

using namespace nerfslam;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::quietLogs();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto in = fuzz::scratchDir() / "camera.yaml";
  const auto out = fuzz::scratchDir() / "saved.yaml";
  fuzz::writeBytes(in, std::string_view(reinterpret_cast<const char*>(data), size));
  Camera cam;
  try {
    cam = loadCameraYaml(in);
  } catch (const Error&) {
    return 0;
  }
  // Loaded cameras are valid: they must write and read back to the identical camera.
  saveCameraYaml(cam, out);
  const Camera back = loadCameraYaml(out);
  if (back.width != cam.width || back.height != cam.height || back.fx != cam.fx || back.fy != cam.fy ||
      back.cx != cam.cx || back.cy != cam.cy || back.distortion_model != cam.distortion_model ||
      back.distortion != cam.distortion) {
    std::fprintf(stderr, "camera YAML round trip changed the camera:\n  loaded %s\n  reloaded %s\n",
                 cam.describe().c_str(), back.describe().c_str());
    std::abort();
  }
  volatile double sink = 0;
  for (const Eigen::Vector2d uv :
       {Eigen::Vector2d(0, 0), Eigen::Vector2d(cam.width - 1, cam.height - 1), Eigen::Vector2d(cam.cx, cam.cy)}) {
    const Eigen::Vector3d ray = cam.unproject(uv);
    const Eigen::Vector2d p = cam.project(ray);
    sink = sink + p.x() + p.y();
  }
  (void)sink;
  return 0;
}
