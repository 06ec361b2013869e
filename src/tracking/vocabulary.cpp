#include "nerfslam/tracking/vocabulary.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <deque>
#include <fstream>
#include <iterator>
#include <random>
#include <sstream>

#include "binary_blob.h"
#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/tracking/frame.h"

namespace nerfslam {
namespace {

constexpr size_t kBytes = 32;
constexpr std::string_view kMagic("NSVOCAB\0", 8);
constexpr size_t kHeaderBytes = 8 + 6 * 4;
constexpr size_t kNodeBytes = 4 + kBytes;

// Hamming distance with the tracker's popcount (runtime-dispatched POPCNT, frame.h).
inline int hamming(const uint8_t* a, const uint8_t* b) { return descriptorDistance(a, b); }

using Centre = std::array<uint8_t, kBytes>;
struct Cluster {
  Centre centre;
  std::vector<uint32_t> members;
};

// Bitwise majority of the descriptors `members` (a bit is set when more than half have it).
Centre majority(const std::vector<const uint8_t*>& d, const std::vector<uint32_t>& members) {
  std::array<uint32_t, kBytes * 8> ones{};
  for (uint32_t m : members) {
    const uint8_t* p = d[m];
    for (size_t b = 0; b < kBytes; ++b)
      for (int j = 0; j < 8; ++j) ones[b * 8 + size_t(j)] += (p[b] >> j) & 1u;
  }
  Centre c{};
  for (size_t b = 0; b < kBytes; ++b)
    for (int j = 0; j < 8; ++j)
      if (2 * size_t(ones[b * 8 + size_t(j)]) > members.size()) c[b] |= uint8_t(1u << j);
  return c;
}

// k-means++ seeding with integer arithmetic only (identical on every run): the first centre
// uniformly, each next one with probability proportional to its squared distance to the nearest.
std::vector<Centre> seedCentres(const std::vector<const uint8_t*>& d, const std::vector<uint32_t>& members, int k,
                                std::mt19937_64& rng) {
  std::vector<Centre> centres;
  const size_t n = members.size();
  auto add = [&](size_t i) {
    Centre c;
    std::memcpy(c.data(), d[members[i]], kBytes);
    centres.push_back(c);
  };
  add(size_t(rng() % n));
  std::vector<uint64_t> dist(n);
  for (size_t i = 0; i < n; ++i) dist[i] = uint64_t(hamming(d[members[i]], centres[0].data()));
  while (int(centres.size()) < k) {
    uint64_t total = 0;
    for (uint64_t x : dist) total += x * x;
    if (total == 0) break;  // every descriptor equals a centre
    const uint64_t r = rng() % total;
    uint64_t acc = 0;
    size_t pick = n - 1;
    for (size_t i = 0; i < n; ++i) {
      acc += dist[i] * dist[i];
      if (acc > r) {
        pick = i;
        break;
      }
    }
    add(pick);
    for (size_t i = 0; i < n; ++i)
      dist[i] = std::min<uint64_t>(dist[i], uint64_t(hamming(d[members[i]], centres.back().data())));
  }
  return centres;
}

// k-medians (k-majority) of one node's descriptors; empty clusters are dropped. With k or fewer
// descriptors, each distinct descriptor is a cluster of its own.
std::vector<Cluster> kMajority(const std::vector<const uint8_t*>& d, const std::vector<uint32_t>& members, int k,
                               int max_iterations, std::mt19937_64& rng) {
  std::vector<Cluster> out;
  if (members.size() <= size_t(k)) {
    for (uint32_t m : members) {
      auto same = std::find_if(out.begin(), out.end(),
                               [&](const Cluster& c) { return std::memcmp(c.centre.data(), d[m], kBytes) == 0; });
      if (same == out.end()) {
        out.push_back({});
        std::memcpy(out.back().centre.data(), d[m], kBytes);
        same = out.end() - 1;
      }
      same->members.push_back(m);
    }
    return out;
  }
  std::vector<Centre> centres = seedCentres(d, members, k, rng);
  const size_t kc = centres.size();
  std::vector<uint32_t> assign(members.size(), ~0u);
  std::vector<std::vector<uint32_t>> groups(kc);
  for (int it = 0; it < max_iterations; ++it) {
    bool changed = false;
    for (auto& g : groups) g.clear();
    for (size_t i = 0; i < members.size(); ++i) {
      uint32_t best = 0;
      int best_d = hamming(d[members[i]], centres[0].data());
      for (size_t c = 1; c < kc; ++c) {
        const int dc = hamming(d[members[i]], centres[c].data());
        if (dc < best_d) best_d = dc, best = uint32_t(c);
      }
      changed |= assign[i] != best;
      assign[i] = best;
      groups[best].push_back(members[i]);
    }
    if (!changed) break;
    for (size_t c = 0; c < kc; ++c)
      if (!groups[c].empty()) centres[c] = majority(d, groups[c]);
  }
  for (size_t c = 0; c < kc; ++c)
    if (!groups[c].empty()) out.push_back({centres[c], std::move(groups[c])});
  return out;
}

void checkDescriptors(const cv::Mat& m, const std::string& what) {
  if (m.empty()) return;
  if (m.type() != CV_8U || size_t(m.cols) != kBytes)
    fail("{}: descriptors must be CV_8U rows of {} bytes (got {} columns of type {})", what, kBytes, m.cols, m.type());
}

}  // namespace

Vocabulary Vocabulary::learn(const std::vector<cv::Mat>& images, const VocabularyOptions& o) {
  if (o.k < 2 || o.k > 64) fail("vocabulary: k must be in 2..64 (got {})", o.k);
  if (o.levels < 1 || o.levels > 8) fail("vocabulary: levels must be in 1..8 (got {})", o.levels);
  if (o.max_iterations < 1) fail("vocabulary: max_iterations must be >= 1 (got {})", o.max_iterations);
  std::vector<const uint8_t*> d;
  std::vector<uint32_t> image_of;
  for (size_t i = 0; i < images.size(); ++i) {
    checkDescriptors(images[i], "vocabulary training image " + std::to_string(i));
    for (int r = 0; r < images[i].rows; ++r) {
      d.push_back(images[i].ptr<uint8_t>(r));
      image_of.push_back(uint32_t(i));
    }
  }
  if (d.empty()) fail("vocabulary: no training descriptors");

  Vocabulary v;
  v.k_ = o.k;
  v.levels_ = o.levels;
  v.parent_.push_back(kNoParent);
  v.descriptors_.assign(kBytes, 0);
  std::mt19937_64 rng(o.seed);
  struct Pending {
    NodeId node;
    std::vector<uint32_t> members;
    int depth;
  };
  std::deque<Pending> queue;
  std::vector<uint32_t> all(d.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = uint32_t(i);
  queue.push_back({0, std::move(all), 0});
  // Breadth first: nodes are split in id order, so their children get increasing ids.
  while (!queue.empty()) {
    Pending p = std::move(queue.front());
    queue.pop_front();
    if (p.depth >= o.levels || p.members.size() <= 1) continue;
    std::vector<Cluster> clusters = kMajority(d, p.members, o.k, o.max_iterations, rng);
    if (clusters.size() <= 1) continue;  // identical descriptors: a leaf
    for (Cluster& c : clusters) {
      const NodeId id = NodeId(v.parent_.size());
      v.parent_.push_back(p.node);
      v.descriptors_.insert(v.descriptors_.end(), c.centre.begin(), c.centre.end());
      queue.push_back({id, std::move(c.members), p.depth + 1});
    }
  }
  v.finish();

  // idf = ln(N / n_w) over the training images with descriptors.
  std::vector<uint32_t> images_with(v.wordCount(), 0), last_image(v.wordCount(), ~0u);
  size_t n_images = 0;
  for (size_t i = 0; i < d.size(); ++i) {
    if (i == 0 || image_of[i] != image_of[i - 1]) ++n_images;
    const WordId w = v.word(d[i]);
    if (last_image[w] != image_of[i]) {
      last_image[w] = image_of[i];
      ++images_with[w];
    }
  }
  v.idf_.resize(v.wordCount());
  for (size_t w = 0; w < v.wordCount(); ++w)
    v.idf_[w] = float(std::log(double(n_images) / double(std::max<uint32_t>(1, images_with[w]))));
  return v;
}

void Vocabulary::finish() {
  const size_t n = parent_.size();
  child_begin_.assign(n, 0);
  child_count_.assign(n, 0);
  depth_.assign(n, 0);
  for (size_t i = 1; i < n; ++i) {
    const NodeId p = parent_[i];
    if (child_count_[p]++ == 0) child_begin_[p] = uint32_t(i);
    depth_[i] = uint8_t(depth_[p] + 1);
  }
  node_word_.assign(n, ~0u);
  word_node_.clear();
  for (size_t i = 0; i < n; ++i)
    if (child_count_[i] == 0) {
      node_word_[i] = WordId(word_node_.size());
      word_node_.push_back(NodeId(i));
    }
}

WordId Vocabulary::word(const uint8_t* descriptor, int level, NodeId* node) const {
  NodeId cur = 0;
  NodeId at_level = 0;
  while (child_count_[cur] > 0) {
    const uint32_t b = child_begin_[cur], e = b + child_count_[cur];
    NodeId best = b;
    int best_d = hamming(descriptor, nodeDescriptor(b));
    for (uint32_t c = b + 1; c < e; ++c) {
      const int dc = hamming(descriptor, nodeDescriptor(c));
      if (dc < best_d) best_d = dc, best = c;
    }
    cur = best;
    if (depth_[cur] <= level) at_level = cur;
  }
  if (node) *node = at_level;
  return node_word_[cur];
}

WordId Vocabulary::word(const uint8_t* descriptor) const { return word(descriptor, 0, nullptr); }

void Vocabulary::transform(const cv::Mat& descriptors, BowVector* bow, FeatureVector* direct, int direct_level) const {
  checkDescriptors(descriptors, "Vocabulary::transform");
  if (empty()) fail("Vocabulary::transform: the vocabulary is empty");
  bow->clear();
  if (direct) direct->clear();
  std::vector<std::pair<WordId, float>> words;
  std::vector<std::pair<NodeId, int>> nodes;
  words.reserve(size_t(descriptors.rows));
  for (int r = 0; r < descriptors.rows; ++r) {
    NodeId node = 0;
    const WordId w = word(descriptors.ptr<uint8_t>(r), direct_level, &node);
    if (idf_[w] > 0) words.emplace_back(w, idf_[w]);
    if (direct) nodes.emplace_back(node, r);
  }
  std::sort(words.begin(), words.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  double total = 0;
  for (const auto& [w, x] : words) {
    if (bow->empty() || bow->back().first != w)
      bow->emplace_back(w, x);
    else
      bow->back().second += x;
    total += x;
  }
  if (total > 0)
    for (auto& e : *bow) e.second = float(e.second / total);
  if (direct) {
    std::sort(nodes.begin(), nodes.end());
    for (const auto& [n, f] : nodes) {
      if (direct->empty() || direct->back().first != n) direct->emplace_back(n, std::vector<int>{});
      direct->back().second.push_back(f);
    }
  }
}

double Vocabulary::score(const BowVector& a, const BowVector& b) {
  // For two L1-normalised non-negative vectors, 1 - |a - b|_1 / 2 = sum over shared words of min(a, b).
  double s = 0;
  auto i = a.begin(), j = b.begin();
  while (i != a.end() && j != b.end()) {
    if (i->first < j->first) {
      ++i;
    } else if (j->first < i->first) {
      ++j;
    } else {
      s += std::min(i->second, j->second);
      ++i, ++j;
    }
  }
  return std::clamp(s, 0.0, 1.0);
}

std::string Vocabulary::serialize() const {
  blob::Writer w;
  w.bytes(kMagic.data(), kMagic.size());
  w.u32(kFileVersion);
  w.u32(uint32_t(kBytes));
  w.u32(uint32_t(k_));
  w.u32(uint32_t(levels_));
  w.u32(uint32_t(wordCount()));
  w.u32(uint32_t(nodeCount()));
  for (size_t i = 0; i < nodeCount(); ++i) {
    w.u32(parent_[i]);
    w.bytes(nodeDescriptor(NodeId(i)), kBytes);
  }
  for (float x : idf_) w.f32(x);
  return w.finish();
}

Vocabulary Vocabulary::deserialize(std::string_view bytes, const std::string& name) {
  blob::Reader r(bytes, name, kMagic);
  const uint32_t version = r.u32("version");
  if (version != kFileVersion)
    throw fieldError(name, "version",
                     fmt::format("vocabulary file version {}, this build reads version {}", version, kFileVersion));
  const uint32_t desc = r.u32("descriptor_bytes");
  if (desc != kBytes)
    throw fieldError(name, "descriptor_bytes",
                     fmt::format("{}-byte descriptors, ours are {}-byte steered BRIEF", desc, kBytes));
  Vocabulary v;
  const uint32_t k = r.u32("k"), levels = r.u32("levels");
  if (k < 2 || k > 64) throw fieldError(name, "k", fmt::format("{} is outside 2..64", k));
  if (levels < 1 || levels > 8) throw fieldError(name, "levels", fmt::format("{} is outside 1..8", levels));
  const uint32_t words = r.u32("word_count"), nodes = r.u32("node_count");
  // Sizes are checked against the file before anything is allocated.
  const uint64_t need_nodes = kHeaderBytes + uint64_t(nodes) * kNodeBytes, need_idf = need_nodes + uint64_t(words) * 4;
  if (bytes.size() < need_nodes + 4)
    throw fieldError(
        name, "node_table",
        fmt::format("truncated: {} nodes need {} bytes, the file has {}", nodes, need_nodes + 4, bytes.size()));
  if (bytes.size() < need_idf + 4)
    throw fieldError(
        name, "idf",
        fmt::format("truncated: {} words need {} bytes, the file has {}", words, need_idf + 4, bytes.size()));
  if (bytes.size() > need_idf + 4)
    throw fieldError(name, "end", fmt::format("{} unexpected trailing bytes", bytes.size() - need_idf - 4));
  r.checkCrc();
  if (nodes < 1) throw fieldError(name, "node_count", "0: a vocabulary has at least its root");
  v.k_ = int(k);
  v.levels_ = int(levels);
  v.parent_.resize(nodes);
  v.descriptors_.resize(size_t(nodes) * kBytes);
  for (uint32_t i = 0; i < nodes; ++i) {
    v.parent_[i] = r.u32("node_table");
    std::memcpy(v.descriptors_.data() + size_t(i) * kBytes, r.take(kBytes, "node_table"), kBytes);
    const NodeId p = v.parent_[i];
    const bool ok = i == 0 ? p == kNoParent : (p < i && (i == 1 || p >= v.parent_[i - 1]));
    if (!ok) throw fieldError(name, fmt::format("node_table[{}].parent", i), "not in breadth-first order");
  }
  v.finish();
  for (uint32_t i = 0; i < nodes; ++i) {
    if (v.child_count_[i] > k)
      throw fieldError(name, fmt::format("node_table[{}]", i),
                       fmt::format("{} children, k is {}", v.child_count_[i], k));
    if (v.depth_[i] > levels)
      throw fieldError(name, fmt::format("node_table[{}]", i),
                       fmt::format("depth {} exceeds {} levels", v.depth_[i], levels));
  }
  if (v.wordCount() != words)
    throw fieldError(name, "word_count", fmt::format("{}, but the node table has {} leaves", words, v.wordCount()));
  v.idf_.resize(words);
  for (uint32_t w = 0; w < words; ++w) {
    v.idf_[w] = r.f32("idf");
    if (!std::isfinite(v.idf_[w]) || v.idf_[w] < 0)
      throw fieldError(name, fmt::format("idf[{}]", w), "not a finite non-negative number");
  }
  r.expectEnd();
  return v;
}

void saveVocabulary(const Vocabulary& vocabulary, const std::filesystem::path& path) {
  writeStringAtomic(path, vocabulary.serialize());
}

Vocabulary loadVocabulary(const std::filesystem::path& path) {
  return Vocabulary::deserialize(readInputFile(path, "vocabulary file"), path.string());
}

}  // namespace nerfslam
