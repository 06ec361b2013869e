// `nerfslam eval`: APE/RPE of an estimated trajectory against a reference, computed like evo
// (evo_ape / evo_rpe) so the numbers can be compared with published ones.
#include <memory>
#include <string>

#include <fmt/format.h>

#include "command.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/trajectory.h"

namespace {

struct EvalArgs {
  std::string ref, est, format = "auto", ref_times, est_times, json;
  nerfslam::eval::TrajectoryEvalOptions options;
};

nerfslam::Trajectory load(const std::string& path, nerfslam::TrajectoryFormat format, const std::string& times) {
  return nerfslam::readTrajectory(path, format, times);
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
          ->check(CLI::NonNegativeNumber);
      sub.add_option("--t-offset", o.est_time_offset, "Time offset (s) added to the estimate's timestamps")
          ->capture_default_str();
      sub.add_option("--delta", o.rpe_delta, "RPE step between pose pairs")
          ->capture_default_str()
          ->check(CLI::PositiveNumber);
      sub.add_option("--delta-unit", o.rpe_delta_unit, "Unit of --delta: frames or m (travelled path)")
          ->capture_default_str()
          ->check(CLI::IsMember({"frames", "m"}));
      sub.add_flag("--pairs-from-reference", o.rpe_pairs_from_reference,
                   "Choose RPE pairs on the reference instead of the estimate");
      sub.add_option("--json", a->json, "Write the results as JSON to this file (atomically)");
      return [a]() -> int {
        const auto format = nerfslam::parseTrajectoryFormat(a->format);
        const nerfslam::Trajectory ref = load(a->ref, format, a->ref_times);
        const nerfslam::Trajectory est = load(a->est, format, a->est_times.empty() ? a->ref_times : a->est_times);
        nerfslam::eval::TrajectoryReport rep;
        try {
          rep = nerfslam::eval::evaluateTrajectory(ref, est, a->options);
        } catch (const nerfslam::Error& e) {
          throw nerfslam::Error(fmt::format("evaluating {} against {}: {}", a->est, a->ref, e.what()));
        }
        fmt::print("reference: {}\nestimate:  {}\n{}", a->ref, a->est, nerfslam::eval::formatReport(rep));
        if (!a->json.empty()) nerfslam::writeStringAtomic(a->json, nerfslam::eval::reportToJson(rep));
        return 0;
      };
    });

}  // namespace
