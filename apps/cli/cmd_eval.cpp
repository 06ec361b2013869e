// `nerfslam eval`: APE/RPE of an estimated trajectory against a reference, computed like evo
// (evo_ape / evo_rpe) so the numbers can be compared with published ones.
#include <filesystem>
#include <memory>
#include <string>

#include <fmt/format.h>

#include "command.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/trajectory.h"

namespace {

struct EvalArgs {
  std::string ref, est, format = "auto", ref_times, est_times, json;
  nerfslam::TrajectoryEvalOptions options;
};

// The file, refused when its timestamps go back (poses out of time order would be associated
// silently with the wrong reference poses); repeated timestamps, which real files have (an OpenVINS
// estimate, a TUM ground truth), are counted in a warning.
nerfslam::Trajectory load(const std::string& path, nerfslam::TrajectoryFormat format, const std::string& times) {
  nerfslam::Trajectory t = nerfslam::readTrajectory(path, format, times);
  std::size_t repeated = 0, first_repeated = 0;
  for (std::size_t i = 1; i < t.size(); ++i) {
    if (t[i].timestamp < t[i - 1].timestamp)
      nerfslam::fail("{}: pose {} (timestamp {}) is before pose {} ({}): a trajectory must be in time order", path,
                     i + 1, nerfslam::numberForMessage(t[i].timestamp), i,
                     nerfslam::numberForMessage(t[i - 1].timestamp));
    if (t[i].timestamp == t[i - 1].timestamp && repeated++ == 0) first_repeated = i + 1;
  }
  if (repeated > 0)
    fmt::print(stderr, "warning: {}: {} pose(s) repeat the previous pose's timestamp (the first: pose {})\n", path,
               repeated, first_repeated);
  return t;
}

nerfslam::cli::Registrar reg(
    "eval", "Evaluate a trajectory against ground truth (evo-compatible APE and RPE)",
    [](CLI::App& sub) -> nerfslam::cli::Runner {
      auto a = std::make_shared<EvalArgs>();
      auto& o = a->options;
      sub.add_option("--ref", a->ref, "Reference (ground-truth) trajectory file")->required();
      sub.add_option("--est", a->est, "Estimated trajectory file")->required();
      sub.add_option("--format", a->format, "File format of both: tum, kitti, euroc or auto (detect from content)")
          ->capture_default_str()
          ->check(CLI::IsMember({"auto", "tum", "kitti", "euroc"}));
      sub.add_option("--ref-times", a->ref_times, "KITTI only: timestamps file of the reference (default: line index)");
      sub.add_option("--est-times", a->est_times,
                     "KITTI only: timestamps file of the estimate (default: --ref-times, else line index)");
      sub.add_option("--align", o.align,
                     "Alignment of the estimate onto the reference: none, se3, sim3 (monocular), scale")
          ->capture_default_str()
          ->check(CLI::IsMember({"none", "se3", "sim3", "scale"}));
      sub.add_option("--max-dt", o.max_dt, "Largest timestamp difference (s) for associating poses")
          ->capture_default_str()
          ->check(nerfslam::cli::kNonNegative);
      sub.add_option("--t-offset", o.est_time_offset, "Time offset (s) added to the estimate's timestamps")
          ->capture_default_str();
      sub.add_option("--delta", o.rpe_delta, "RPE step between pose pairs")
          ->capture_default_str()
          ->check(nerfslam::cli::kPositive);
      sub.add_option("--delta-unit", o.rpe_delta_unit, "Unit of --delta: frames or m (travelled path)")
          ->capture_default_str()
          ->check(CLI::IsMember({"frames", "m"}));
      sub.add_flag("--pairs-from-reference", o.rpe_pairs_from_reference,
                   "Choose RPE pairs on the reference instead of the estimate");
      sub.add_option("--json", a->json, "Write the results as JSON to this file (atomically)");
      return [a]() -> int {
        for (const std::string* input : {&a->ref, &a->est, &a->ref_times, &a->est_times})
          if (!a->json.empty() && !input->empty() && nerfslam::sameFile(a->json, *input))
            nerfslam::fail("eval: --json {} is one of the inputs; choose another output file", a->json);
        const auto format = nerfslam::parseTrajectoryFormat(a->format);
        const nerfslam::Trajectory ref = load(a->ref, format, a->ref_times);
        const nerfslam::Trajectory est = load(a->est, format, a->est_times.empty() ? a->ref_times : a->est_times);
        nerfslam::TrajectoryReport rep;
        try {
          rep = nerfslam::evaluateTrajectory(ref, est, a->options);
        } catch (const nerfslam::Error& e) {
          throw nerfslam::Error(fmt::format("evaluating {} against {}: {}", a->est, a->ref, e.what()));
        }
        fmt::print("reference: {}\nestimate:  {}\n{}", a->ref, a->est, nerfslam::formatReport(rep));
        if (!a->json.empty()) nerfslam::writeStringAtomic(a->json, nerfslam::reportToJson(rep));
        return 0;
      };
    });

}  // namespace
