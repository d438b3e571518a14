// MP4 (H.264, yuv420p) from rendered frames through the ffmpeg program:
// frames are piped to it as raw rgb24 (no shell: fork/exec with an argument
// vector), it writes a temp file beside the target, which is renamed on success.
#pragma once
#include <string>

#include <ATen/ATen.h>

namespace flat::exporter {

bool ffmpeg_available();  // an executable `ffmpeg` on PATH

// frames (K,3,H,W) float in [0,1] (clamped, rounded to 8 bit), K >= 1, any
// device; odd H or W are padded to even by repeating the last row / column
// (yuv420p needs even sizes). fps > 0. Throws flat::Error naming the path, with
// ffmpeg's exit status and the tail of its stderr when it fails.
void write_mp4(const std::string& path, const at::Tensor& frames, double fps);

}  // namespace flat::exporter
