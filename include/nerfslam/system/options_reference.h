#pragma once
// The reference of every option the `run` and `train` configurations accept, generated from the
// option structs (see include/nerfslam/core/options.h). docs/options.md embeds this text; a test
// keeps the two identical.
#include <string>

namespace nerfslam {

// Markdown: one section per configuration (run: SystemOptions, train: TrainOptions), each a table of
// path, type, default, constraint and meaning.
std::string optionReferenceMarkdown();
// `path = value  # meaning` for every option at its default.
std::string optionDefaultsText();

}  // namespace nerfslam
