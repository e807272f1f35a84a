#include "coordinator/testing/in_process_farm.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>

#include "services/scene/bundle.h"

namespace prism::coordinator::testing {

namespace fs = std::filesystem;

const char kSmallScene[] = R"(LookAt 0 0 -5  0 0 0  0 1 0
Camera "perspective" "float fov" 30
Film "spectral" "integer xresolution" 16 "integer yresolution" 16 "integer nbuckets" 8
Sampler "zsobol" "integer pixelsamples" 4
Integrator "volpath" "integer maxdepth" 5
WorldBegin
LightSource "infinite" "spectrum L" [360 1 830 1] "float scale" 1
AttributeBegin
  Material "diffuse" "float reflectance" 0.5
  Shape "sphere" "float radius" 0.8
AttributeEnd
)";

std::string packed_bundle(const fs::path& root, const std::string& text) {
  fs::create_directories(root);
  std::ofstream(root / "scene.pbrt", std::ios::binary) << text;
  auto bundle = scene::make_bundle(root, "scene.pbrt", {});
  EXPECT_TRUE(bundle.ok()) << bundle.status();
  return bundle.ok() ? scene::pack(*bundle) : std::string();
}

std::unique_ptr<InProcessFarm> InProcessFarm::start(
    const fs::path& data_dir, const std::function<void(FarmOptions&)>& adjust) {
  FarmOptions options;
  options.data_dir = data_dir;
  options.scheduler.heartbeat_interval = Millis(200);
  options.tick_interval = Millis(20);
  if (adjust) adjust(options);
  auto farm = FarmCoordinator::open(std::move(options));
  EXPECT_TRUE(farm.ok()) << farm.status();
  if (!farm.ok()) return nullptr;
  std::unique_ptr<InProcessFarm> out(new InProcessFarm());
  out->farm_ = *std::move(farm);
  rpc::ServerConfig config;
  config.api_token = kApiToken;
  config.worker_secret = kWorkerSecret;
  auto server = rpc::CoordinatorServer::start(*out->farm_, config, spdlog::default_logger());
  EXPECT_TRUE(server.ok()) << server.status();
  if (!server.ok()) return nullptr;
  out->server_ = *std::move(server);
  return out;
}

InProcessFarm::~InProcessFarm() {
  if (server_) server_->shutdown(Millis(100));
  server_.reset();
  farm_.reset();
}

}  // namespace prism::coordinator::testing
