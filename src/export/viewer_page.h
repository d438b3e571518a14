// The viewer's index.html (our own page; three.js does the WebGL work).
#pragma once

namespace flat::exporter {

// The first line names it, so that write_viewer() recognises a folder it
// wrote before and may replace it.
constexpr const char* kViewerMarker = "<!-- FLAT-C++ viewer";

const char* viewer_index_html();

}  // namespace flat::exporter
