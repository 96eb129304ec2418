# proden entry points. Each target is idempotent and does all of its own set-up on Debian 12
# (dependencies via tools/install-deps.sh, configure, build).
#   make build   install deps if missing, Release build into build/ (CLI at build/proden)
#   make test    build, run the whole CTest suite, then the unit and daemon tests again under
#                ASan+UBSan, the daemon and service tests under ThreadSanitizer (build-tsan/),
#                and each libFuzzer target for a short smoke (make fuzz-smoke)
#   make run     build and start the daemon (`proden serve`) with a demo job fed by the samples
#   make run-cli build and run the CLI on the bundled samples
#   make training-data  render the learned mixer's training/validation frames with Blender and
#                compute their inputs with proden (slow, resumable; TRAINING_DATA, default
#                /work/trainingdata; training/README.md)
#   make train   train both network widths on that data and export weights + parity fixtures
#                (PyTorch from Debian, CPU; training/TRAINING.md); `make validate` prints the
#                validation table of both mixers as proden runs them
#   make soak    build, then soak the daemon on loopback for SOAK_MINUTES (default 30): 200 SSE
#                clients, 20 passes/s (uploads and watched files), kill -9 every 3 minutes; writes
#                bench/results/soak.md (+ soak_rss.png) and fails on any error (bench/soak.py)
#   make fuzz    build the libFuzzer targets into build-fuzz/ (clang, ASan+UBSan) and run each one
#                in turn until FUZZ_RUNS executions or FUZZ_SECONDS seconds (per target), growing
#                build-fuzz/fuzz/corpus/; writes bench/results/fuzz.md (fuzz/README.md)
#   make fuzz-smoke  each fuzz target FUZZ_SMOKE_SECONDS on the committed corpus (part of make test),
#                built in the ASan tree (build-asan/)
#   make bench   build the benchmarks into build-bench/, render missing evaluation sets (EVALDATA,
#                default /work/evaldata; slow on a fresh machine), regenerate bench/results/ and
#                bench/RESULTS.md (bench/run_all.sh documents its variables)
.PHONY: build test run run-cli deps asan test-asan tsan test-tsan format clean bench training-data \
        train validate soak fuzz fuzz-build fuzz-smoke

BUILD_DIR ?= build
ASAN_DIR  ?= build-asan
TSAN_DIR  ?= build-tsan
JOBS      ?= $(shell nproc)
comma := ,
WERROR    ?= ON
OUT_DIR   ?= out
BENCH_DIR ?= build-bench
FUZZ_DIR  ?= build-fuzz
FUZZ_SECONDS ?= 7200        # per target; the campaign stops earlier at FUZZ_RUNS executions
FUZZ_RUNS ?= 10000000
FUZZ_TARGETS ?= pass_reader,weights,frame_state,job_config,http_request,watch_pattern
FUZZ_SMOKE_SECONDS ?= 20
# Unity builds (CMake batches of 8 sources compiled as one): each batch parses the Boost, Beast,
# OIIO and Catch2 headers once instead of eight times. make test's Release tree builds in 4.8
# minutes instead of 7.9 (bench/RESULTS.md "make test's own time"). UNITY=OFF builds file by file,
# faster when one source changes.
UNITY     ?= ON
# Ninja: a target's sources compile while the libraries it links are still being built (the
# Makefile generator waits for each library first), so the two cores stay busy along the chain
# pipeline -> io -> protocol -> daemon -> tests (bench/RESULTS.md "make test's own time").
GENERATOR ?= Ninja
CMAKE_COMMON = -G "$(GENERATOR)" -DCMAKE_UNITY_BUILD=$(UNITY) -DPRODEN_WERROR=$(WERROR)
# CMake refuses to reconfigure a tree with another generator: such a tree (e.g. one made before
# the switch to Ninja) is configured afresh (its cache removed; outputs are rebuilt).
same_generator = @if [ -f $(1)/CMakeCache.txt ] && \
	  ! grep -qx 'CMAKE_GENERATOR:INTERNAL=$(GENERATOR)' $(1)/CMakeCache.txt; then \
	  echo "$(1): configured with another generator; configuring it afresh for $(GENERATOR)"; \
	  rm -rf $(1)/CMakeCache.txt $(1)/CMakeFiles; fi

deps:
	@tools/install-deps.sh

build: deps
	$(call same_generator,$(BUILD_DIR))
	cmake -S . -B $(BUILD_DIR) -DCMAKE_BUILD_TYPE=Release $(CMAKE_COMMON)
	cmake --build $(BUILD_DIR) -j $(JOBS)

# The 2-minute soak (label soak) is left out: `cd build && ctest -L soak`, or `make soak`.
test: build test-asan test-tsan fuzz-smoke
	cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS) -LE soak

# Debug (assertions on) at -O1: the sanitizers' usual level, several times faster than -O0 for the
# pipeline's tests (the tiled-equals-whole test took 5.5 minutes at -O0), stack traces intact.
# -gline-tables-only: a report's frames keep function, file and line, and the tree builds in
# 8.6 minutes instead of 9.7 with full -g (2 cores, bench/RESULTS.md "make test's own time").
# clang, with libFuzzer's coverage instrumentation too (PRODEN_FUZZ): the same tree builds the
# fuzz targets for make fuzz-smoke, so make test compiles the sanitized libraries once.
# proden_asan_targets (unit and daemon tests, fuzz targets) and proden_tsan_targets are one goal
# each, which -j builds in parallel with either generator (the Makefile generator builds targets
# named one by one after another).
asan: deps
	$(call same_generator,$(ASAN_DIR))
	cmake -S . -B $(ASAN_DIR) -DCMAKE_BUILD_TYPE=Debug "-DCMAKE_CXX_FLAGS_DEBUG=-gline-tables-only -O1" \
	      -DCMAKE_CXX_COMPILER=clang++ -DPRODEN_SANITIZE=ON -DPRODEN_FUZZ=ON \
	      $(CMAKE_COMMON) -DPRODEN_BUILD_BENCH=OFF
	cmake --build $(ASAN_DIR) -j $(JOBS) --target proden_asan_targets

# The sanitizer configuration runs the unit tests and the daemon's unit tests (the CLI/integration
# tests run in the Release tree).
test-asan: asan
	cd $(ASAN_DIR) && ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 \
	  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 ctest --output-on-failure -L 'unit|daemon' -j $(JOBS)

# The ThreadSanitizer configuration builds only the daemon and its tests, and runs the daemon's
# unit tests and the service tests (tests/service/*.py against the TSan-built daemon; a TSan
# report fails the test). -g1: line tables and functions, all a report's stacks need, and a third
# less compile time than -g for the Beast-heavy sources. The pipeline's heavy math is built without
# TSan there (pipeline/CMakeLists.txt): it runs single-threaded on a worker's own scratch.
tsan: deps
	$(call same_generator,$(TSAN_DIR))
	cmake -S . -B $(TSAN_DIR) -DCMAKE_BUILD_TYPE=RelWithDebInfo \
	      "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O2 -g1 -DNDEBUG" -DPRODEN_TSAN=ON \
	      $(CMAKE_COMMON) -DPRODEN_BUILD_BENCH=OFF
	cmake --build $(TSAN_DIR) -j $(JOBS) --target proden_tsan_targets

test-tsan: tsan
# A TSan build runs library thread pools (TBB, OIIO, OpenEXR) on their caller's thread, the CLI's
# too (service/thread_limit.hpp).
	cd $(TSAN_DIR) && ctest --output-on-failure -L 'daemon|service' -j $(JOBS)

run: build
	OUT_DIR=$(OUT_DIR) tools/run-daemon.sh

run-cli: build
	@mkdir -p $(OUT_DIR)
	$(BUILD_DIR)/proden info samples/renders/cornell/pass_00.exr samples/renders/povray/pass_00.exr
	$(BUILD_DIR)/proden denoise --aov --out $(OUT_DIR)/cornell.exr samples/renders/cornell/pass_*.exr
	$(BUILD_DIR)/proden denoise --aov --out $(OUT_DIR)/textured_dof.exr samples/renders/textured_dof/pass_*.exr
	$(BUILD_DIR)/proden eval --ref samples/renders/cornell/reference.exr \
	    samples/renders/cornell/pass_00.exr $(OUT_DIR)/cornell.exr
	@echo "outputs in $(OUT_DIR)/"

# libFuzzer targets (fuzz/): clang 14 + compiler-rt from Debian, every proden library instrumented.
# The smoke runs them from the ASan tree (above); a campaign builds an optimised tree of its own.
FUZZ_TARGET_NAMES = $(addprefix fuzz_,$(subst $(comma), ,$(FUZZ_TARGETS)))

fuzz-smoke: asan
	cmake --build $(ASAN_DIR) -j $(JOBS) --target $(FUZZ_TARGET_NAMES)
	fuzz/run.py smoke $(ASAN_DIR) --seconds $(FUZZ_SMOKE_SECONDS) --targets $(FUZZ_TARGETS)

fuzz-build: deps
	$(call same_generator,$(FUZZ_DIR))
	cmake -S . -B $(FUZZ_DIR) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ \
	      -G "$(GENERATOR)" -DCMAKE_UNITY_BUILD=$(UNITY) -DPRODEN_FUZZ=ON -DPRODEN_BUILD_TESTS=OFF -DPRODEN_BUILD_BENCH=OFF
	cmake --build $(FUZZ_DIR) -j $(JOBS) --target $(FUZZ_TARGET_NAMES)

fuzz: fuzz-build
	fuzz/run.py campaign $(FUZZ_DIR) --seconds $(FUZZ_SECONDS) --runs $(FUZZ_RUNS) \
	    --targets $(FUZZ_TARGETS)

bench: deps
	@tools/install-deps.sh blender   # renders the evaluation sets it lacks
	$(call same_generator,$(BENCH_DIR))
	cmake -S . -B $(BENCH_DIR) -DCMAKE_BUILD_TYPE=Release $(CMAKE_COMMON)
	cmake --build $(BENCH_DIR) -j $(JOBS) --target proden_eval_levels proden_bench_pipeline \
	    proden_bench_network proden_micro_kernels proden_bench_nfor proden_nfor_eval
	BUILD_DIR=$(BENCH_DIR) bench/run_all.sh

SOAK_MINUTES ?= 30

soak: build
	nice -n 10 /usr/bin/python3 bench/soak.py --minutes $(SOAK_MINUTES) --binary $(BUILD_DIR)/proden \
	    --report bench/results/soak.md --png bench/results/soak_rss.png

TRAIN_BUDGET ?= 1440   # seconds of training per width (both widths train at once, 1 thread each)

training-data: build
	PRODEN=$(BUILD_DIR)/proden training/generate.sh

# The committed weights came from exactly this (training/TRAINING.md; --steps/--calib in
# training/runs/w*/summary.json "reproduce" replays a budget run step for step).
train: deps
	for w in 48 24; do \
	  /usr/bin/python3 training/train.py --width $$w --budget $(TRAIN_BUDGET) --crop 64 --batch 12 \
	      --max-lr 2e-3 --threads 1 --seed 1 --log-every 50 --val-every 1000 \
	      --out training/runs/w$$w & \
	done; wait
	for w in 48 24; do \
	  /usr/bin/python3 training/export.py --model training/runs/w$$w/model.pt \
	      --weights training/weights/pdnet_w$$w.pdnw --fixture tests/data/pdnet_parity_w$$w.bin \
	      || exit 1; \
	done
	cp training/weights/pdnet_w48.pdnw training/weights/pdnet.pdnw   # the built-in network

validate: build
	/usr/bin/python3 training/validate.py --proden $(BUILD_DIR)/proden

format:
	clang-format -i $$(git ls-files '*.cpp' '*.hpp')

clean:
	rm -rf $(BUILD_DIR) $(ASAN_DIR) $(TSAN_DIR) $(FUZZ_DIR)
