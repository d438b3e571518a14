// 3DGS-ecosystem PLY for the Gaussian baselines (gaussian_ply.h has the layout).
#include "flat/export/gaussian_ply.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::exporter {
namespace {

constexpr double kSH0 = 0.28209479177387814;  // degree-0 real spherical harmonic

std::vector<std::string> property_names(int64_t scales) {
  std::vector<std::string> p = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"};
  for (int64_t k = 0; k < scales; ++k) p.push_back("scale_" + std::to_string(k));
  for (int k = 0; k < 4; ++k) p.push_back("rot_" + std::to_string(k));
  return p;
}

}  // namespace

void write_gaussian_ply(const std::string& path, const primitives::GaussianSoup& g) {
  check_shape(g.means, {-1, 3}, "gaussian ply: means", "(N,3)");
  const int64_t n = g.means.size(0);
  FLAT_CHECK(g.scales.dim() == 2 && g.scales.size(0) == n && (g.scales.size(1) == 3 || g.scales.size(1) == 2),
             "gaussian ply: scales must be (N,3) or (N,2) with N = " + std::to_string(n) + ", got " +
                 shape_str(g.scales));
  check_shape(g.rotations, {n, 4}, "gaussian ply: rotations", "(N,4)");
  check_shape(g.colors, {n, 3}, "gaussian ply: colors", "(N,3)");
  check_shape(g.opacities, {n}, "gaussian ply: opacities", "(N)");
  const auto cpu = [](const at::Tensor& t) { return t.detach().to(at::kCPU, at::kFloat); };
  const int64_t k = g.scales.size(1);
  // Columns in file order, each (N,1).
  const auto rgb = cpu(g.colors), o = cpu(g.opacities).clamp(1e-6, 1 - 1e-6);
  const auto q = cpu(g.rotations);
  std::vector<at::Tensor> cols = {cpu(g.means), at::zeros({n, 3}), (rgb - 0.5) / kSH0, at::log(o / (1 - o)).unsqueeze(1),
                                  at::log(cpu(g.scales)), q / q.norm(2, 1, true).clamp_min(1e-12)};
  const at::Tensor table = at::cat(cols, 1).contiguous();  // (N, 10 + k + 4)
  check_finite(table, "gaussian ply: " + path + " (means, log scales, logit opacities)");
  const auto names = property_names(k);
  write_file_atomic(path, [&](std::ostream& out) {
    out << "ply\nformat binary_little_endian 1.0\ncomment FLAT " << (k == 3 ? "3DGS" : "2DGS")
        << " Gaussians (docs/formats.md)\nelement vertex " << n << "\n";
    for (const auto& p : names) out << "property float " << p << "\n";
    out << "end_header\n";
    out.write(reinterpret_cast<const char*>(table.data_ptr<float>()), std::streamsize(table.numel() * sizeof(float)));
  });
}

primitives::GaussianSoup read_gaussian_ply(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  FLAT_CHECK(in.good(), path + ": cannot open");
  std::string line;
  std::getline(in, line);
  FLAT_CHECK(line == "ply", path + ": not a PLY file");
  int64_t n = -1;
  std::vector<std::string> props;
  bool in_vertex = false, binary = false;
  while (std::getline(in, line) && line != "end_header") {
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") {
      std::string fmt;
      ls >> fmt;
      binary = fmt == "binary_little_endian";
    } else if (word == "element") {
      std::string name;
      ls >> name >> n;
      in_vertex = name == "vertex";
      FLAT_CHECK(in_vertex, path + ": unexpected element '" + name + "' (a Gaussian PLY has only vertices)");
    } else if (word == "property" && in_vertex) {
      std::string type, name;
      ls >> type >> name;
      FLAT_CHECK(type == "float", path + ": property '" + name + "' is " + type + ", expected float");
      props.push_back(name);
    }
  }
  FLAT_CHECK(line == "end_header", path + ": the header does not end (truncated file?)");
  FLAT_CHECK(binary, path + ": only binary_little_endian Gaussian PLY files are read");
  FLAT_CHECK(n >= 0, path + ": no vertex element");
  std::map<std::string, int64_t> column;
  for (size_t i = 0; i < props.size(); ++i) column[props[i]] = int64_t(i);
  const int64_t k = column.count("scale_2") ? 3 : 2;
  for (const auto& p : property_names(k))
    if (p[0] != 'n') FLAT_CHECK(column.count(p), path + ": missing property '" + p + "'");
  at::Tensor table = at::empty({n, int64_t(props.size())}, at::kFloat);
  in.read(reinterpret_cast<char*>(table.data_ptr<float>()), std::streamsize(table.numel() * sizeof(float)));
  FLAT_CHECK(in.gcount() == std::streamsize(table.numel() * sizeof(float)),
             path + ": truncated (" + std::to_string(n) + " vertices announced)");
  const auto col = [&](const std::string& p) { return table.select(1, column[p]); };
  const auto cols = [&](const std::string& stem, int64_t count) {
    std::vector<at::Tensor> c;
    for (int64_t i = 0; i < count; ++i) c.push_back(col(stem + std::to_string(i)));
    return at::stack(c, 1);
  };
  primitives::GaussianSoup g;
  g.means = at::stack({col("x"), col("y"), col("z")}, 1);
  g.colors = cols("f_dc_", 3) * kSH0 + 0.5;
  g.opacities = at::sigmoid(col("opacity"));
  g.scales = at::exp(cols("scale_", k));
  g.rotations = cols("rot_", 4);
  return g;
}

}  // namespace flat::exporter
