# ipm — run `make help` for the targets.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCH_VERSION := 2.13.0
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.DEFAULT_GOAL := help

help: ## list the targets
	@grep -E '^[a-zA-Z0-9_-]+:.*?## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*?## "}; {printf "  \033[36m%-16s\033[0m %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==$(TORCH_VERSION)
	$(BIN)/python -m pip install --quiet -e '.[dev,viz,dist,bench]'
	@touch $(STAMP)

install: $(STAMP) ## create .venv (torch 2.13 CPU first, then the project)

demo: $(STAMP) ## run the main job on built-in data and print where the results are
	$(BIN)/ipm demo results/demo

test: $(STAMP) ## run the full test suite
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

test-fast: $(STAMP) ## the inner loop: everything but the tests marked slow, stop at the first failure
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -x -m "not slow"

lint: $(STAMP) ## ruff over the package and tests, and the import contracts of docs/architecture.md
	$(BIN)/ruff check ipm tests benchmarks
	$(BIN)/lint-imports

bench: $(STAMP) ## speed benchmarks, written under results/perf/
	$(BIN)/python -m benchmarks.run results/perf

# Bench tables: each resumes an interrupted run and rewrites its tables; FRESH=1 recomputes every cell.
WORKERS ?= 2
define run_bench
	$(if $(FRESH),rm -rf results/$(2),)
	$(BIN)/ipm bench experiments/$(1).toml -o results/$(2) --workers $(WORKERS) --resume $(3)
endef

bench-small: $(STAMP) ## the small experiment (1 real mug, seconds), results/small/
	$(call run_bench,small,small)

table1: $(STAMP) ## the Table-1 analogue on its tune split: 22 real meshes, fits from 1, 2 and 4 views, results/table1/
	$(call run_bench,table1,table1,--split tune)

table-validation: $(STAMP) ## the same table on the validation split (24 real meshes never tuned on), results/table_validation/
	$(call run_bench,table1,table_validation,--split validation)

split-report: $(STAMP) ## tune against validation per class, and issue #34's checks, from the two tables' rows: results/split.md
	$(BIN)/python -m benchmarks.split_report results

table-synthetic: $(STAMP) ## generator samples with known parameters, results/table_synthetic/
	$(call run_bench,table_synthetic,table_synthetic)

table-coverage: $(STAMP) ## what the generators can take (8-view bound) beside the K = 1 fits, results/table_coverage/
	$(call run_bench,table_coverage,table_coverage)

table-sections: $(STAMP) ## dishes samples whose body is not round in section, fitted from 1 and 2 views, results/table_sections/
	$(call run_bench,table_sections,table_sections)

coverage-validation: $(STAMP) ## the same on the validation split's vessels and buildings (reported only), results/coverage_validation/ (18 minutes, 2 workers)
	$(call run_bench,coverage_validation,coverage_validation)

weights: $(STAMP) ## retrain the neural-subdivision weights shipped in the package (about a minute on 2 cores)
	$(BIN)/ipm train-subdivision -o ipm/subdiv/weights/neural_dishes.npz --pairs 32 --steps 1500 --seed 0

proposals: $(STAMP) ## retrain the proposal networks shipped in the package (ipm fit --init; 17 and 16 minutes on a busy 2-core machine)
	$(BIN)/ipm train-proposals dishes -o ipm/proposals/weights/dishes.npz --samples 45000 --steps 8000 --workers 2 --seed 0
	$(BIN)/ipm train-proposals building -o ipm/proposals/weights/building.npz --samples 45000 --steps 8000 --workers 2 --seed 0

table-proposals: $(STAMP) ## the proposal networks alone on held-out generator samples, results/table_proposals/
	$(call run_bench,table_proposals,table_proposals)

table-init: $(STAMP) ## K = 1 fits started from the presets, the learned proposals or both, results/table_init/
	$(call run_bench,table_init,table_init)

bench-ambiguity: $(STAMP) ## is a weak K = 1 cell the search's or the view's? every tune target of table_coverage: results/ambiguity.md (buildings) and ambiguity_vessels.md (6 and 10 minutes side by side, one thread each)
	$(BIN)/python -m benchmarks.ambiguity building building_2 building_3 building_4 building_5 building_6 -o results/ambiguity.md
	$(BIN)/python -m benchmarks.ambiguity cup_1 cup_2 bowl plate pitcher teapot bottle vase -o results/ambiguity_vessels.md

bench-ambiguity-views: $(STAMP) ## do tune fits miss what other view counts found? vessels at 4 views against 2, buildings at 2 against 4: results/ambiguity_views*.md (5 and 4 minutes side by side, one thread each)
	$(BIN)/python -m benchmarks.ambiguity cup_1 cup_2 bowl plate pitcher teapot bottle vase sugar_bowl plate_round --experiment experiments/table1.toml --views 4 --against ipm:2 -o results/ambiguity_views.md
	$(BIN)/python -m benchmarks.ambiguity building building_2 building_3 building_4 building_5 building_6 munich_2869646 munich_2869655 munich_2870516 --experiment experiments/table1.toml --views 2 --against ipm:4 -o results/ambiguity_views_buildings.md

bench-ambiguity-validation: $(STAMP) ## the same for every K = 1 cell of the validation split's vessels and buildings: results/ambiguity_validation.md and ambiguity_validation_buildings.md (15 and 10 minutes side by side, one thread each)
	$(BIN)/python -m benchmarks.ambiguity coffee_can evo_bowl mug_lowpoly mustard plate_8in plate_square saucer shallow_bowl teaset_cup teaset_teapot tumbler --experiment experiments/coverage_validation.toml -o results/ambiguity_validation.md
	$(BIN)/python -m benchmarks.ambiguity montreal_326de407 montreal_bce4a7a6 montreal_energy munich_2869644 munich_2869645 munich_2869664 munich_2869678 munich_2869708 storey_3 --experiment experiments/coverage_validation.toml -o results/ambiguity_validation_buildings.md

table-subdiv: $(STAMP) ## subdivision table: decimated closed meshes, midpoint / Loop / neural, results/table_subdiv/ (about 15 minutes: it trains 10 networks)
	$(BIN)/python -m benchmarks.table_subdiv results/table_subdiv

table-subdiv-fit: $(STAMP) ## fits rendering a subdivided coarse level of detail against finer ones (real mug), results/subdiv_fit/
	$(call run_bench,subdiv_fit,subdiv_fit)

table-curves: $(STAMP) ## vectorizing 22 line drawings with exact curves, clean and degraded: ipm, skeleton, potrace, results/table_curves/ (about 2 minutes)
	$(BIN)/python -m benchmarks.table_curves results/table_curves

bench-transport: $(STAMP) ## soft IoU against sinkhorn / sliced where fit and target do not overlap, results/transport.md (about 8 minutes)
	$(BIN)/python -m benchmarks.transport -o results/transport.md

bench-profile: $(STAMP) ## real vessels' side views: 2D profiles fitted and revolved, results/profile_fit.md (about a minute)
	$(BIN)/python -m benchmarks.profile_fit -o results/profile_fit.md

table-gear: $(STAMP) ## the plug-in tutorial's benchmark (docs/plugins.md): random gears from 2 views, results/gear/ (about 4 minutes)
	$(BIN)/ipm --plugin docs/examples/gear.py bench docs/examples/gear.toml -o results/gear --workers $(WORKERS)

bench-structure-masks: $(STAMP) ## structure search from 4 masks: 84ed15d's 32² rays against this tree's, alternating, results/structure_masks.md (about 40 minutes)
	IPM_THREADS=1 $(BIN)/python -m benchmarks.structure_masks results

table-structure: $(STAMP) ## structure search from meshes: random trees and real furniture against fixed trees, BSP and an SDF grid, results/table_structure/ (about 30 minutes)
	$(BIN)/python -m benchmarks.table_structure results/table_structure

openscad: ## install OpenSCAD (Debian's package) unless it is there: the tests and table-exports render .scad programs with it
	@command -v openscad >/dev/null || ($(SUDO) apt-get update -qq && $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq openscad)

cad: $(STAMP) ## install the cad extra (CadQuery with OCP and VTK, about 1.4 GB) into .venv: runs the CadQuery programs
	$(BIN)/python -m pip install --quiet -e '.[cad]'

table-exports: $(STAMP) openscad cad ## OpenSCAD and CadQuery programs of the tree presets and searched trees against the exact mesh, results/exports/
	$(BIN)/python -m benchmarks.program_exports results/exports

cadquery-booleans: $(STAMP) cad ## how often CadQuery programs of 162 trees (random ones on a grid too) give the right solid, results/exports/cadquery_booleans.md
	$(BIN)/python -m benchmarks.cadquery_booleans results/exports

exact-mesh: $(STAMP) ## exact CSG meshes against marching cubes: seconds, watertight, sharp edges kept (csg preset, 10 random trees), results/exact_mesh/ (seconds)
	$(BIN)/python -m benchmarks.exact_mesh results/exact_mesh

table-convert: $(STAMP) ## mesh conversion table (bsp, perturb, dense SDF grid), results/table_convert/
	$(BIN)/python -m benchmarks.table_convert results/table_convert

clean: ## remove caches (keeps .venv)
	rm -rf .pytest_cache .ruff_cache build *.egg-info

.PHONY: help install demo test test-fast lint bench bench-small table-gear table1 table-validation split-report table-synthetic table-coverage table-sections coverage-validation weights proposals table-proposals table-init bench-ambiguity bench-ambiguity-views bench-ambiguity-validation table-subdiv table-subdiv-fit table-curves bench-transport bench-profile table-convert bench-structure-masks table-structure exact-mesh openscad cad table-exports cadquery-booleans clean

bench-perturbation: $(STAMP) ## does a fit's answer hinge on noise? 6 fits x 6 perturbations (kernel, threads, SIMD, 1e-6 moves), results/perturbation.md (about 15 minutes)
	$(BIN)/python -m benchmarks.perturbation -o results/perturbation.md
