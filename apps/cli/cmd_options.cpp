// `nerfslam options`: the reference of every option a --config YAML may set, generated from the
// option structs' `visit` methods (the same walk the loader and validator use).
#include <iostream>
#include <memory>
#include <string>

#include "command.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/system/options_reference.h"

namespace {

struct OptionsArgs {
  bool markdown = false;
  bool defaults = false;
  std::string out;
};

nerfslam::cli::Registrar reg("options", "Print every configuration option (path, type, default, constraint, meaning)",
                             [](CLI::App& sub) -> nerfslam::cli::Runner {
                               auto a = std::make_shared<OptionsArgs>();
                               sub.add_flag("--markdown", a->markdown, "Markdown tables (as in docs/options.md)");
                               sub.add_flag("--defaults", a->defaults,
                                            "The default values as 'path = value  # meaning' lines");
                               sub.add_option("--out", a->out,
                                              "Write to this file (atomically) instead of standard output");
                               return [a]() -> int {
                                 const std::string text =
                                     a->defaults ? nerfslam::optionDefaultsText() : nerfslam::optionReferenceMarkdown();
                                 if (a->out.empty())
                                   std::cout << text;
                                 else
                                   nerfslam::writeStringAtomic(a->out, text);
                                 return 0;
                               };
                             });

}  // namespace
