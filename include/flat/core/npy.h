// NumPy .npy files (format versions 1.0, 2.0 and 3.0), read strictly.
//
// Why our own reader: Debian 12 packages no cnpy (libcnpy-dev does not exist)
// and xtensor-dev's xnpy.hpp (0.24.3, checked 2026-11) reads only versions 1
// and 2, has no float16 (it needs a C++ element type per dtype and refuses any
// other), makes the caller know the dtype before reading, and would bring
// xtensor + xtl (large template libraries) into the build and onto the GPU
// machine's carry for ~200 lines of work. The format is small and documented
// (numpy.lib.format):
//   "\x93NUMPY" major minor, header length (uint16 LE for 1.x, uint32 LE for
//   2.x/3.x), then a Python dict literal padded with spaces and ended by '\n':
//   {'descr': '<f4', 'fortran_order': False, 'shape': (480, 640), }
//   then the raw array bytes.
// Strict means: the dict holds exactly those three keys, once each (as numpy's
// own reader requires); descr is a simple dtype (no structured or object
// arrays); the data size equals prod(shape) * itemsize exactly (a truncated or
// over-long file is refused); big-endian data is refused; every error names
// the file. The header parser needs no libtorch (a fuzz target can link it).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/ATen.h>

namespace flat {

struct NpyHeader {
  int major = 0, minor = 0;
  std::string descr;           // as written, e.g. "<f4", "|u1"
  char kind = 0;               // 'f' float, 'i' signed, 'u' unsigned, 'b' bool
  int64_t itemsize = 0;        // bytes per element
  bool fortran_order = false;  // column-major data
  std::vector<int64_t> shape;  // () for a scalar
  int64_t data_offset = 0;     // bytes before the array data
  int64_t numel() const;
};

// Parses the start of an .npy file (at least the magic, the length field and
// the header; more bytes are ignored). `where` (the file name) prefixes every
// error. Throws flat::Error.
NpyHeader parse_npy_header(const char* data, size_t size, const std::string& where);

// Reads an .npy file into a CPU tensor of its dtype (float16/32/64, bool,
// int8/16/32/64, uint8); Fortran order is refused (re-save it with
// numpy.ascontiguousarray). Throws flat::Error naming the file.
at::Tensor read_npy(const std::string& path);

// Writes a CPU tensor of one of those dtypes as a version 1.0 .npy file (C
// order, little-endian, header padded to 64 bytes as numpy does); atomic.
void write_npy(const std::string& path, const at::Tensor& tensor);

}  // namespace flat
