#!/usr/bin/env bash
# Sourced by the GPU scripts before they build: ninja rebuilds by modification
# time, and the device tool re-sends the working tree with times that can be
# older than objects an earlier call built from other contents (a patched
# variant of gpu_raster_ab.sh, say): that build would then be stale. Each
# build folder keeps the hashes of the sources it was last built from; files
# whose contents differ now are touched.
#   sync_mtimes ROOT BUILD
sync_mtimes() {
  local root="$1" build="$2" manifest="$2/.source_hashes"
  mkdir -p "$build"
  (cd "$root" && find src include apps tests data_tools cmake CMakeLists.txt -type f -print0 | xargs -0 sha1sum | sort -k2) \
    >"$manifest.new"
  if [ -f "$manifest" ]; then
    join -1 2 -2 2 -a 2 -e missing -o 2.2,1.1,2.1 "$manifest" "$manifest.new" | awk '$2 != $3 {print $1}' |
      (cd "$root" && xargs -r touch)
  fi
  mv "$manifest.new" "$manifest"
}
