// Disjoint sets over 0..n-1 (path halving, union by size): the connected
// components of mesh_statistics, floater pruning and vertex stitching.
#pragma once
#include <cstdint>
#include <utility>
#include <vector>

namespace flat::mesh {

class UnionFind {
 public:
  explicit UnionFind(int64_t n) : parent_(size_t(n)), size_(size_t(n), 1), count_(n) {
    for (int64_t i = 0; i < n; ++i) parent_[size_t(i)] = i;
  }
  int64_t find(int64_t x) {
    while (parent_[size_t(x)] != x) {
      parent_[size_t(x)] = parent_[size_t(parent_[size_t(x)])];
      x = parent_[size_t(x)];
    }
    return x;
  }
  void unite(int64_t a, int64_t b) {
    a = find(a);
    b = find(b);
    if (a == b) return;
    if (size_[size_t(a)] < size_[size_t(b)]) std::swap(a, b);
    parent_[size_t(b)] = a;
    size_[size_t(a)] += size_[size_t(b)];
    --count_;
  }
  int64_t count() const { return count_; }                          // number of sets
  int64_t size_of(int64_t x) { return size_[size_t(find(x))]; }     // members of x's set
  // Each element's set as 0..count()-1, numbered in order of first appearance.
  std::vector<int64_t> labels() {
    std::vector<int64_t> root_label(parent_.size(), -1), out(parent_.size());
    int64_t next = 0;
    for (size_t i = 0; i < parent_.size(); ++i) {
      auto& l = root_label[size_t(find(int64_t(i)))];
      if (l < 0) l = next++;
      out[i] = l;
    }
    return out;
  }

 private:
  std::vector<int64_t> parent_, size_;
  int64_t count_;
};

}  // namespace flat::mesh
