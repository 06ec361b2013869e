#include "nerfslam/system/options_reference.h"

#include "nerfslam/core/options_yaml.h"
#include "nerfslam/nerf/nerf_options.h"
#include "nerfslam/system/slam_system.h"

namespace nerfslam {

std::string optionReferenceMarkdown() {
  std::string md;
  md += "### `nerfslam run --config FILE` (SystemOptions, include/nerfslam/system/slam_system.h)\n\n";
  md += documentOptions<SystemOptions>();
  md += "\n### NeRF training (TrainOptions, include/nerfslam/nerf/nerf_options.h)\n\n";
  md += documentOptions<nerf::TrainOptions>();
  return md;
}

std::string optionDefaultsText() {
  std::string text = "# nerfslam run --config\n";
  text += printOptions(SystemOptions{});
  text += "# NeRF training\n";
  text += printOptions(nerf::TrainOptions{});
  return text;
}

}  // namespace nerfslam
