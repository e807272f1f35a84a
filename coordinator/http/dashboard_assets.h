// The dashboard's static files (coordinator/http/dashboard/), compiled into the coordinator by
// cmake/embed_dashboard.cmake so that it serves them with no files to install. The page uses no
// JavaScript library: it draws with the canvas API and talks to the HTTP/JSON API.
#pragma once

#include <string_view>
#include <vector>

namespace prism::coordinator::http {

struct DashboardAsset {
  std::string_view name;  // e.g. "app.js", served as /dashboard/app.js
  std::string_view content_type;
  std::string_view content;
};

const std::vector<DashboardAsset>& dashboard_assets();

}  // namespace prism::coordinator::http
