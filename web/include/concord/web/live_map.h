#pragma once
/// \file
/// The live map page (web/assets/live_map.html, built into the binary): a self-contained HTML
/// page that polls a robot's JSON endpoints and its neighbours' (through /peers) and draws the
/// team's trajectories and objects with their uncertainty ellipses.

#include <string_view>

namespace concord::web {

/// The page's HTML (UTF-8), valid for the program's lifetime.
std::string_view live_map_page();

}  // namespace concord::web
