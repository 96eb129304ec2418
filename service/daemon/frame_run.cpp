#include "daemon/frame_run.hpp"

#include <fcntl.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "daemon/files.hpp"
#include "daemon/frame_history.hpp"
#include "daemon/pass_source.hpp"
#include "daemon/processor.hpp"
#include "daemon/versions.hpp"
#include "proden/error.hpp"
#include "proden/error_estimate.hpp"
#include "proden/hash.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/protocol/estimate.hpp"
#include "proden/protocol/json.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;
using nlohmann::json;
using Steady = std::chrono::steady_clock;

namespace {

double seconds_since(Steady::time_point t0) {
  return std::chrono::duration<double>(Steady::now() - t0).count();
}

// The frame status fields an event repeats.
// One version as FrameHistory keeps it and events carry it (docs/api.md).
json version_summary(const FrameRecord& rec) {
  return {{"version", rec.version},
          {"updated", rec.updated},
          {"passes", rec.passes},
          {"spp", rec.spp},
          {"estimated_mse", rec.estimated_mse},
          {"estimated_error", rec.estimated_error},
          {"converged", rec.convergence.converged()}};
}

json frame_event(const protocol::JobSpec& spec, const FrameRecord& rec) {
  json d = version_summary(rec);
  d.update({{"job", spec.id}, {"name", spec.name}, {"frame", rec.frame}});
  return d;
}

}  // namespace

fs::path output_base(const protocol::JobSpec& spec, long frame) {
  return fs::path(spec.output.dir) /
         protocol::expand_output_name(spec.output.name, spec.name, frame);
}

bool pass_less(const std::string& a, const std::string& b) {
  const bool na = !a.empty() && a.size() < 19 && std::all_of(a.begin(), a.end(), ::isdigit);
  const bool nb = !b.empty() && b.size() < 19 && std::all_of(b.begin(), b.end(), ::isdigit);
  if (na && nb) {
    const long long x = std::stoll(a), y = std::stoll(b);
    return x != y ? x < y : a < b;
  }
  if (na != nb) return na;
  return a < b;
}

void publish_error(EventHub& events, const std::string& job, long frame, const std::string& pass,
                   const std::string& path, const std::string& kind, const std::string& message,
                   bool quarantined) {
  events.publish("error", {{"job", job},
                           {"frame", frame},
                           {"pass", pass},
                           {"path", path},
                           {"kind", kind},
                           {"message", message},
                           {"quarantined", quarantined}});
}

FrameRun::FrameRun(JobStore& store, Metrics& metrics, EventHub& events, Hooks hooks)
    : store_(store), metrics_(metrics), events_(events), hooks_(std::move(hooks)) {}

FrameRun::Outcome FrameRun::run(Input in) {
  const protocol::JobSpec& spec = in.spec;
  const std::string& job_id = spec.id;
  const long frame_no = in.frame;
  FrameRecord rec = std::move(in.record);
  std::shared_ptr<FrameAccumulator> acc = std::move(in.acc);
  std::shared_ptr<AovAccumulator> aovs = std::move(in.aovs);
  std::vector<PendingPass>& batch = in.batch;
  std::sort(batch.begin(), batch.end(),
            [](const PendingPass& a, const PendingPass& b) { return pass_less(a.pass, b.pass); });
  const fs::path state_file = store_.state_path(job_id, frame_no);

  // 1. The frame's state: resident, persisted (or the last good one), or new.
  try {
    if (!acc || !aovs) {
      aovs = std::make_shared<AovAccumulator>();
      if (in.has_state) {
        const auto t0 = Steady::now();
        JobStore::LoadedState loaded = store_.load_frame(job_id, frame_no);
        acc = std::make_shared<FrameAccumulator>(std::move(loaded.acc));
        *aovs = std::move(loaded.aovs);
        metrics_.observe("proden_stage_duration_seconds", "load", seconds_since(t0));
        if (!loaded.damage.empty()) {
          // Versions only increase: the next one follows the newest known.
          loaded.record.version = std::max(loaded.record.version, rec.version);
          rec = std::move(loaded.record);
          const std::string msg = loaded.damage + "; recovered the last good state (version " +
                                  std::to_string(rec.version) + ", " + std::to_string(rec.passes) +
                                  " passes); the passes after it are read again";
          spdlog::error("job {} frame {}: {}", job_id, frame_no, msg);
          metrics_.inc("proden_errors_total", "corrupt_state");
          publish_error(events_, job_id, frame_no, "", state_file.string(), "corrupt_state", msg,
                        false);
          hooks_.recovered(rec);
          in.republish = false;
        }
      } else {  // quarters only when the pipeline cross-validates on them (NFOR, the cascade)
        acc = std::make_shared<FrameAccumulator>(AccumulatorOptions{
            .quarters = FrameProcessor::estimate_options(spec.pipeline).quarters});
      }
    }
  } catch (const std::exception& e) {
    spdlog::error("job {} frame {}: cannot load state: {}", job_id, frame_no, e.what());
    return {Result::state_unreadable, nullptr, nullptr, false, e.what()};
  }

  // A version committed but not published (killed, or its publish failed, in between) is
  // published as itself before new passes make the next one: every version is published, in
  // the history and announced (docs/api.md, "kill -9 at any moment loses nothing").
  if (in.republish && !batch.empty()) {
    Outcome o = commit_and_publish(spec, frame_no, rec, acc, aovs, {}, {}, 0, in.roots);
    if (o.result != Result::done) return o;
    in.republish = false;
  }

  // 2. Read and accumulate each pass; a pass that fails is reported and left out.
  io::ReadOptions ro;
  ro.renderer = io::parse_renderer(spec.renderer).value_or(io::Renderer::automatic);
  ro.spp = spec.spp;
  ro.view_layer = spec.view_layer;
  ro.limits = in.limits;
  // A pass of another size than the frame's is refused from its header, before decoding.
  if (in.has_state && rec.width > 0 && rec.height > 0)
    ro.frame_size = std::pair{rec.width, rec.height};
  std::vector<protocol::PassIdentity> accepted;
  std::vector<PendingPass> accepted_passes;
  std::uint64_t accepted_bytes = 0;
  for (const auto& p : batch) {
    try {
      auto t0 = Steady::now();
      // Opened once, at the moment of use: beneath its root, within the read limits.
      store_.fault_point("read", p.path);
      auto src = read_pending_pass(p, in.roots, ro, spec.output.aovs);
      if (!src) continue;  // gone or changed: the watcher offers it again once it settles
      const std::uint64_t size = src->size;
      protocol::PassIdentity id{p.pass, p.path.string(), size, src->mtime_ns, src->content_hash};
      const Pass& pass = src->pass;
      if (!std::isfinite(pass.spp) || pass.spp > protocol::kMaxPassSpp) {
        throw InputError(InputErrorKind::invalid_value, p.path.string(),
                         "samples per pixel " + std::to_string(pass.spp) +
                             " is beyond the largest accepted (1048576)");
      }
      const io::PassInfo& info = src->info;
      const std::vector<AovChannel>& pass_aovs = src->aovs;
      metrics_.observe("proden_stage_duration_seconds", "read", seconds_since(t0));
      t0 = Steady::now();
      const AddResult r = acc->add(pass, p.pass);
      // The colour was accepted: its AOVs follow (same size; nothing in add() throws then).
      aovs->add(pass_aovs, pass.spp, info.aov_attributes);
      if (rec.renderer.empty()) {
        rec.renderer = std::string(io::to_string(info.renderer));
        rec.view_layer = info.layer;
        rec.view_layers = info.layers;
      }
      metrics_.observe("proden_stage_duration_seconds", "accumulate", seconds_since(t0));
      if (r.dropped_pixels > 0) {
        spdlog::warn("{}: {} non-finite pixel(s) dropped", p.path.string(), r.dropped_pixels);
      }
      accepted.push_back(id);
      accepted_passes.push_back(p);
      accepted_bytes += size;
    } catch (...) {
      hooks_.failed(p, classify_current_exception());
    }
  }

  if (accepted.empty() && !in.republish) return {Result::done, acc, aovs, false, {}};
  return commit_and_publish(spec, frame_no, rec, acc, aovs, accepted, accepted_passes,
                            accepted_bytes, in.roots);
}

// 3. Commit (persist) the accepted passes, if any, then publish the frame's version.
FrameRun::Outcome FrameRun::commit_and_publish(const protocol::JobSpec& spec, long frame_no,
                                               FrameRecord& rec,
                                               const std::shared_ptr<FrameAccumulator>& acc,
                                               const std::shared_ptr<AovAccumulator>& aovs,
                                               const std::vector<protocol::PassIdentity>& accepted,
                                               const std::vector<PendingPass>& accepted_passes,
                                               std::uint64_t accepted_bytes, const Roots* roots) {
  const std::string& job_id = spec.id;
  bool committed = false;
  std::vector<std::uint64_t> dropped_versions;
  try {
    // The new statistics are written (and made durable) while the estimate and the pipeline
    // run: only the record, which needs their result, is left for the commit below.
    std::unique_ptr<FrameStateWriter> state;
    if (!accepted.empty()) state = store_.begin_frame_save(job_id, frame_no, *acc, *aovs);
    auto t0 = Steady::now();
    const FrameEstimate est = acc->estimate(FrameProcessor::estimate_options(spec.pipeline));
    metrics_.observe("proden_stage_duration_seconds", "estimate", seconds_since(t0));
    ErrorContext ectx;
    ectx.spp = acc->total_spp();
    ectx.passes = acc->passes();
    ectx.noise_scope = rec.renderer == "cycles" ? NoiseScope::pixel : NoiseScope::frame;
    const ProcessedFrame out = FrameProcessor::process(*acc, est, spec.pipeline, ectx);
    for (const auto& [stage, s] : out.stage_seconds) {
      metrics_.observe("proden_stage_duration_seconds", stage, s);
    }
    if (!accepted.empty() &&
        (!std::isfinite(out.estimated_mse) || !std::isfinite(acc->total_spp()))) {
      // These passes would poison the frame (non-finite statistics or estimates): refuse them
      // and keep the persisted state (the resident one is dropped: it holds them).
      std::string names;
      for (const auto& a : accepted) names += (names.empty() ? "" : ", ") + a.pass;
      for (const auto& p : accepted_passes) {
        hooks_.failed(
            p, {ErrorClass::bad_input, "invalid_value",
                "accumulating pass(es) " + names + " would make the frame's estimates non-finite"});
      }
      return {Result::done, nullptr, nullptr, false, {}};
    }
    if (!accepted.empty()) {
      rec.frame = frame_no;
      rec.version += 1;
      rec.updated = protocol::now_rfc3339();
      rec.estimated_mse = out.estimated_mse;
      rec.estimated_mse_source = out.estimated_mse_source;
      rec.passes = acc->passes();
      rec.spp = acc->total_spp();
      rec.width = acc->width();
      rec.height = acc->height();
      rec.inputs = acc->layout().to_string();
      rec.variance_source = std::string(protocol::to_string(est.variance_source));
      rec.low_confidence = est.low_confidence();
      rec.ingested.insert(rec.ingested.end(), accepted.begin(), accepted.end());
      rec.estimated_error = protocol::to_json(out.run.estimated_error);
      rec.aovs = json::array();
      for (const auto& [name, mode] : aovs->channels()) {
        rec.aovs.push_back({{"name", name}, {"mode", to_string(mode)}});
      }
      const auto transition =
          rec.convergence.update(spec.target, spec.min_passes, rec.passes, rec.low_confidence,
                                 out.run.estimated_error, rec.version, rec.updated);
      if (transition == Convergence::Transition::converged) {
        metrics_.inc("proden_frames_converged_total");
      } else if (transition == Convergence::Transition::unconverged) {
        metrics_.inc("proden_frames_unconverged_total");
      }
      dropped_versions = add_version(rec.versions, rec.version, spec.output.history);
      t0 = Steady::now();
      rec.digest = state->digest();  // waits for the statistics to be written
      // The commit point: statistics and pass identities together, atomically.
      store_.commit_frame(job_id, *state, rec);
      committed = true;
      metrics_.observe("proden_stage_duration_seconds", "persist", seconds_since(t0));
      hooks_.committed(rec, accepted);
      metrics_.inc("proden_passes_ingested_total", {}, static_cast<double>(accepted.size()));
      metrics_.inc("proden_ingested_bytes_total", {}, static_cast<double>(accepted_bytes));
      // The accumulated uploads back the last good state until the next commit.
      std::vector<PendingPass> uploads;
      for (const auto& p : accepted_passes) {
        if (p.upload) uploads.push_back(p);
      }
      try {
        store_.keep_uploads(job_id, frame_no, uploads);
      } catch (const std::exception& e) {  // committed: a restart cleans up what is left
        spdlog::warn("job {} frame {}: keeping uploads: {}", job_id, frame_no, e.what());
      }
    }
    t0 = Steady::now();
    // The output directory is opened (and created) beneath its root now, and the files are
    // written through that descriptor: a symlink swapped in since the job was created is refused.
    UniqueFd out_dir;
    if (roots) {
      FileError fe = FileError::none;
      std::string why;
      out_dir = roots->make_dirs(spec.output.dir, fe, why);
      if (!out_dir) throw std::runtime_error("output.dir " + spec.output.dir + ": " + why);
    } else {
      fs::create_directories(spec.output.dir);
      out_dir = UniqueFd(::open(spec.output.dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
    }
    const io::OutputDirectory bound(spec.output.dir, out_dir.get());
    store_.fault_point("publish", output_base(spec, frame_no));
    protocol::Attributes extra = {
        {"proden:version", std::to_string(rec.version)},
        {"proden:converged", rec.convergence.converged() ? "true" : "false"},
    };
    if (!rec.view_layer.empty()) extra.emplace_back("proden:view_layer", rec.view_layer);
    // `auto`: uncompressed now, so the version is out sooner; the engine compresses the file
    // once it is idle (docs/api.md, output.compression).
    protocol::OutputSpec output = spec.output;
    const bool compress_later = spec.output.compression == "auto";
    if (compress_later) {
      output.compression = "none";
      metrics_.inc("proden_publish_uncompressed_total");
    }
    const auto outputs = FrameProcessor::publish(out, output_base(spec, frame_no).string(), output,
                                                 extra, aovs.get());
    // Older versions stay addressable (docs/api.md, "History and older versions"): the
    // versions/ directory is made beneath the output root like output.dir itself.
    if (roots) {
      FileError fe = FileError::none;
      std::string why;
      if (!roots->make_dirs(spec.output.dir + "/versions", fe, why)) {
        throw std::runtime_error("output.dir " + spec.output.dir + "/versions: " + why);
      }
    }
    keep_version(outputs.front(), version_file(spec, frame_no, rec.version));
    for (const auto& v : dropped_versions) {
      std::error_code ec;
      fs::remove(version_file(spec, frame_no, v), ec);
    }
    // What the version is worth (FrameHistory: the dashboard's accuracy chart, farm scripts;
    // the event: one summary, the calibrated estimate included). The history line goes before
    // the version is recorded as published: killed in between, the version is published again
    // on restart (one line per version: FrameHistory::load), so every published version is in
    // the history even when its event was lost with the process (events live in memory).
    json entry = version_summary(rec);
    entry["render_mse"] = out.render_mse;
    try {
      FrameHistory::append(store_.history_path(job_id, frame_no), entry);
    } catch (const std::exception& e) {  // a history line lost; the version itself stands
      spdlog::warn("job {} frame {}: history: {}", job_id, frame_no, e.what());
    }
    store_.save_published(job_id, frame_no, rec.version);
    metrics_.observe("proden_stage_duration_seconds", "publish", seconds_since(t0));
    hooks_.published(rec.version, outputs, compress_later);
    metrics_.inc("proden_frame_updates_total");
    json data = entry;
    data.update({{"job", job_id},
                 {"name", spec.name},
                 {"frame", frame_no},
                 {"new_passes", accepted.size()},
                 {"outputs", outputs}});
    events_.publish("frame", data);
    // The convergence change of this version, announced once it is published (again after a
    // crash between commit and publish: at least once).
    if (const auto t = rec.convergence.transition_at(rec.version);
        t != Convergence::Transition::none) {
      json ev = frame_event(spec, rec);
      ev["target"] = spec.target ? protocol::to_json(*spec.target) : json();
      ev["min_passes"] = spec.min_passes;
      if (t == Convergence::Transition::unconverged) {
        ev["reason"] =
            "version " + std::to_string(rec.version) + " misses the target with confidence";
      }
      events_.publish(t == Convergence::Transition::converged ? "converged" : "unconverged", ev);
      spdlog::info("job {} frame {}: {} at version {}", job_id, frame_no,
                   t == Convergence::Transition::converged ? "converged" : "unconverged",
                   rec.version);
    }
    spdlog::info("job {} frame {}: version {} ({} pass(es), {} spp)", job_id, frame_no, rec.version,
                 rec.passes, rec.spp);
    return {Result::done, acc, aovs, committed, {}};
  } catch (const std::exception& e) {
    // Persist or publish failed (disk full, permissions): drop the resident state so the next
    // run reloads what is on disk; the engine retries the passes (or the publish) later.
    spdlog::error("job {} frame {}: {}", job_id, frame_no, e.what());
    metrics_.inc("proden_errors_total", "publish");
    publish_error(events_, job_id, frame_no, "", "", "publish", e.what(), false);
    return {Result::failed, nullptr, nullptr, committed, e.what()};
  }
}

}  // namespace proden::daemon
