#pragma once
// Parsing of small values given on the command line or in launch arguments ("1,2,3", "640x480").
#include <string>
#include <vector>

namespace nerfslam {

// Comma-separated finite numbers; spaces around each are allowed, an empty text is no number.
// Throws Error "WHAT 'TEXT': 'ITEM' is not a finite number" on anything else (nan, inf, "1x", "").
std::vector<double> parseNumberList(const std::string& text, const std::string& what);

// "WIDTHxHEIGHT" (or "WIDTHXHEIGHT") with both sides integers in [min_side, 8192]. Throws Error
// naming WHAT and the text otherwise.
void parseImageSize(const std::string& text, const std::string& what, int min_side, int* width, int* height);

}  // namespace nerfslam
