// Gaussian PLY in the 3DGS ecosystem's layout: the property names and their
// encodings (logit opacity, log scales, SH DC colour), the round trip, 2DGS'
// two scales, and clear errors.
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/export/gaussian_ply.h"
#include "test_support.h"

using flat::exporter::read_gaussian_ply;
using flat::exporter::write_gaussian_ply;
using flat::primitives::GaussianSoup;

namespace {

GaussianSoup random_gaussians(int64_t n, int64_t scales) {
  auto g = at::make_generator<at::CPUGeneratorImpl>(5);
  auto q = at::randn({n, 4}, g);
  return {at::randn({n, 3}, g), at::rand({n, scales}, g) + 0.01, q / q.norm(2, 1, true), at::rand({n, 3}, g),
          at::rand({n}, g) * 0.9 + 0.05};
}

std::string header_of(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line, header;
  while (std::getline(in, line) && line != "end_header") header += line + "\n";
  return header;
}

}  // namespace

TEST_CASE("gaussian ply: the 3DGS layout, its encodings, and the round trip", "[export][ply]") {
  auto dir = flat::test::scratch_dir("gaussian_ply");
  const auto path = (dir / "g3.ply").string();
  auto g = random_gaussians(9, 3);
  write_gaussian_ply(path, g);
  const auto header = header_of(path);
  CHECK(header.find("element vertex 9\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\n") !=
        std::string::npos);
  CHECK(header.find("property float f_dc_2\nproperty float opacity\nproperty float scale_0\nproperty float "
                    "scale_1\nproperty float scale_2\nproperty float rot_0\n") != std::string::npos);
  // The raw floats of Gaussian 4: logit opacity, log scale, (c - 0.5) / C0.
  std::ifstream in(path, std::ios::binary);
  std::string line;
  while (std::getline(in, line) && line != "end_header") {
  }
  std::vector<float> row(17);
  in.seekg(std::streamoff(4 * 17 * sizeof(float)), std::ios::cur);
  in.read(reinterpret_cast<char*>(row.data()), std::streamsize(row.size() * sizeof(float)));
  const double o = g.opacities[4].item<double>();
  CHECK(row[9] == Approx(std::log(o / (1 - o))).epsilon(1e-5));
  CHECK(row[10] == Approx(std::log(g.scales[4][0].item<double>())).epsilon(1e-5));
  CHECK(row[6] == Approx((g.colors[4][0].item<double>() - 0.5) / 0.28209479177387814).epsilon(1e-5));
  auto r = read_gaussian_ply(path);
  CHECK(torch::allclose(r.means, g.means));
  CHECK(torch::allclose(r.scales, g.scales, 1e-5, 1e-7));
  CHECK(torch::allclose(r.rotations, g.rotations, 1e-5, 1e-7));
  CHECK(torch::allclose(r.colors, g.colors, 1e-5, 1e-6));
  CHECK(torch::allclose(r.opacities, g.opacities, 1e-5, 1e-6));
}

TEST_CASE("gaussian ply: 2DGS surfels carry two scales", "[export][ply]") {
  auto dir = flat::test::scratch_dir("gaussian_ply_2dgs");
  const auto path = (dir / "g2.ply").string();
  write_gaussian_ply(path, random_gaussians(4, 2));
  const auto header = header_of(path);
  CHECK(header.find("scale_1\nproperty float rot_0") != std::string::npos);
  CHECK(header.find("scale_2") == std::string::npos);
  CHECK(read_gaussian_ply(path).scales.size(1) == 2);
}

TEST_CASE("gaussian ply: bad shapes, non-finite values and truncated files are named", "[export][ply]") {
  auto dir = flat::test::scratch_dir("gaussian_ply_errors");
  const auto path = (dir / "bad.ply").string();
  auto g = random_gaussians(3, 3);
  auto wrong = g;
  wrong.scales = at::ones({3, 4});
  REQUIRE_THROWS_WITH(write_gaussian_ply(path, wrong), FLAT_CONTAINS("scales must be (N,3) or (N,2)"));
  auto nan = g;
  nan.means = g.means.clone();
  nan.means[1][2] = NAN;
  REQUIRE_THROWS_WITH(write_gaussian_ply(path, nan), FLAT_CONTAINS("gaussian ply"));
  CHECK_FALSE(std::filesystem::exists(path));  // nothing half-written left behind
  write_gaussian_ply(path, g);
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 10);
  REQUIRE_THROWS_WITH(read_gaussian_ply(path), FLAT_CONTAINS("truncated"));
}
