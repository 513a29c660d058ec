# calib: two commands on a fresh clone -> `make calibrate` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
CALIB  := $(VENV)/bin/calib
PAPER  := sample_runs/paper
DATA   := sample_data/paper
SMOKE  := sample_runs/smoke
PHOTOS := sample_data/photos
SIM    := --preset smoke --workers 2

.PHONY: setup test test-all calibrate paper calibration calibration-spring smoke hidden-effect control-lab hidden-wall hidden-floor default-bbd default-bbd-half-g default-bbd-stiff default-bbd-50mpa default-bbd-150mpa default-bbd-walls sample-photos docs clean

setup: $(VENV)/.installed

# torch is pinned (==2.13.0, CPU wheel) in pyproject.toml: an unpinned torch pulls a multi-GB CUDA build.
# constraints.txt pins the numerical stack the sample runs were made with (a heap's last bits depend on it)
$(VENV)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -c constraints.txt -e '.[test]'
	touch $@

test: setup
	$(PY) -m pytest -q -m "not slow"

test-all: setup
	$(PY) -m pytest -q

# the main job on the shipped sample data: the paper's chain on its published tables, then a
# whole calibration from the sample photographs on simulations at the `default` numerics (~7 min from
# nothing; ~4 on a fresh clone, whose committed stages are up to date: only the design heaps re-simulate)
calibrate: paper calibration

# Table 1 -> target, Tables 3 and 5 -> screening and ascent, into run directory $(1)
define paper_screening
$(CALIB) init --run $(1) --settings stages/settings/paper.toml
$(CALIB) measure-angle --run $(1) --angles $(DATA)/table1_angles.csv
$(CALIB) pb design --run $(1)
$(CALIB) pb analyze --run $(1) --responses $(DATA)/table3_pb.csv
$(CALIB) ascent design --run $(1)
$(CALIB) ascent analyze --run $(1) --responses $(DATA)/table5_ascent.csv
endef

# The paper's chain from its own published data: Table 1 -> target; Tables 3, 5, 7 -> Tables 4, 6, 8, Eq. 7;
# surrogates compared in-sample and held out (Table 9); GA inversion to the measured 32.07 deg (Eq. 11)
paper: setup
	$(call paper_screening,$(PAPER))
	$(CALIB) bbd design --run $(PAPER)
	$(CALIB) bbd analyze --run $(PAPER) --responses $(DATA)/table7_bbd.csv
	$(CALIB) fit-surrogate --run $(PAPER)
	$(CALIB) invert --run $(PAPER)
	$(CALIB) report --run $(PAPER)

# A whole calibration on simulations, in minutes: photographs -> screening -> ascent -> BBD ->
# surrogates -> inversion -> validation runs -> compare, every simulation with the smoke preset
smoke: setup
	$(CALIB) init --run $(SMOKE) --settings stages/settings/smoke.toml
	$(CALIB) measure-angle --run $(SMOKE) --images $(PHOTOS) --conditions $(PHOTOS)/conditions.csv
	$(CALIB) pb design --run $(SMOKE)
	$(CALIB) simulate-heap --run $(SMOKE) --design $(SMOKE)/pb/design.parquet $(SIM)
	$(CALIB) pb analyze --run $(SMOKE)
	$(CALIB) ascent design --run $(SMOKE)
	$(CALIB) simulate-heap --run $(SMOKE) --design $(SMOKE)/ascent/design.parquet $(SIM)
	$(CALIB) ascent analyze --run $(SMOKE)
	$(CALIB) bbd design --run $(SMOKE)
	$(CALIB) simulate-heap --run $(SMOKE) --design $(SMOKE)/bbd/design.parquet $(SIM)
	$(CALIB) bbd analyze --run $(SMOKE)
	$(CALIB) fit-surrogate --run $(SMOKE)
	$(CALIB) invert --run $(SMOKE) --validate 3 $(SIM)
	$(CALIB) compare --run $(SMOKE) --repeats 3 $(SIM)
	$(CALIB) report --run $(SMOKE)

# A whole calibration from photographs (sample_data/calibration: five heaps of 4-5 mm grains poured
# from a 40 mm cylinder): screening -> ascent -> BBD -> surrogates -> inversion -> validation ->
# compare, every simulation at the `default` numerics on the photographed rig (~1,200 grains a heap)
CAL    := sample_runs/calibration
CDATA  := sample_data/calibration
CSIM   := --preset default --workers 2
# the chain into run directory $(1), every design heap simulated with the extra options $(2)
define calibration_chain
$(CALIB) init --run $(1) --settings stages/settings/calibration.toml
$(CALIB) measure-angle --run $(1) --images $(CDATA) --conditions $(CDATA)/conditions.csv
$(CALIB) pb design --run $(1)
$(CALIB) simulate-heap --run $(1) --design $(1)/pb/design.parquet --conditions $(1)/measure/conditions.parquet $(CSIM) $(2)
$(CALIB) pb analyze --run $(1)
$(CALIB) ascent design --run $(1)
$(CALIB) simulate-heap --run $(1) --design $(1)/ascent/design.parquet --conditions $(1)/measure/conditions.parquet $(CSIM) $(2)
$(CALIB) ascent analyze --run $(1)
$(CALIB) bbd design --run $(1)
$(CALIB) simulate-heap --run $(1) --design $(1)/bbd/design.parquet --conditions $(1)/measure/conditions.parquet $(CSIM) $(2)
$(CALIB) bbd analyze --run $(1)
$(CALIB) fit-surrogate --run $(1)
$(CALIB) invert --run $(1) --validate 5 $(CSIM)
$(CALIB) compare --run $(1) --repeats 3 $(CSIM)
$(CALIB) report --run $(1)
endef

calibration: setup
	$(call calibration_chain,$(CAL),)

# The same calibration on the rolling spring (rolling_spring = 1, docs/physics.md "Rolling spring"):
# the BBD's law is handed on to the validation and compare heaps (~7 min)
calibration-spring: setup
	$(call calibration_chain,sample_runs/calibration-spring,--set rolling_spring=1)

# The discrepancy loop on a synthetic lab with hidden cohesion (docs/tutorial-hidden-effect.md):
# calibrate the starting model on all conditions, compare, diagnose, add the effect, recalibrate, compare.
# The lab varies grain size and fill height (heap size) at the `default` numerics: smoke heaps scatter
# too much to see a missing effect (~60 min on 2 cores)
LAB    := sample_runs/hidden-effect
LABSIM := --preset default --workers 2
# the lab's conditions: two grain sizes x three fill heights, ten heaps each (a heap of ~400-1,600
# grains scatters by ~5 deg from pile to pile: ten heaps put its mean within ~1.6 deg)
LABCOND := --sizes 4-5,5-6 --cylinders 40 --fills 50,75,100 --repeats 10 --preset default --workers 2
REV1   := -s 'bbd.factors=["static_friction","rolling_friction","surface_energy"]'

# revision 0 on the lab in $(1)/lab: calibrate on every condition at once (checked and corrected by
# simulation exactly as revision 1 is, so that compare judges the model and not the surrogate's error
# at its optimum), compare, diagnose with
# $(2) heaps per condition and step. A small missing effect needs more: the wall and floor labs' rev-0
# errors (~1.2 deg) are a third of the cohesion lab's, and with 2 heaps a step their diagnose ranked
# noise (wall friction last, p 0.76); with 6 it ranked wall friction first (p 3e-5, and 2e-6 on the
# committed sample run)
define lab_rev0
$(CALIB) init --run $(1) --settings stages/settings/hidden-effect.toml
$(CALIB) measure-angle --run $(1) --images $(1)/lab --conditions $(1)/lab/conditions.csv
$(CALIB) bbd design --run $(1)
$(CALIB) simulate-heap --run $(1) --design $(1)/bbd/design.parquet --conditions $(1)/measure/conditions.parquet $(LABSIM)
$(CALIB) fit-surrogate --run $(1) --from-simulations bbd
$(CALIB) invert --run $(1) --validate 4 --refine 2 $(LABSIM)
$(CALIB) compare --run $(1) --repeats 8 $(LABSIM)
$(CALIB) diagnose --run $(1) --repeats $(2) $(LABSIM)
endef

# revision 1 on the lab in $(1): add effect $(2), recalibrate with the settings overrides in the variable
# named $(3) (a name: the overrides hold commas), restitution held at the BBD's 0.3; the inversion is
# checked with 4 heaps per condition and corrected up to twice where they miss (invert --refine), compare
define lab_rev1
$(CALIB) model add $(2) --run $(1)
$(CALIB) bbd design --run $(1) $($(3))
$(CALIB) simulate-heap --run $(1) --design $(1)/bbd/design.parquet --conditions $(1)/measure/conditions.parquet $(LABSIM)
$(CALIB) fit-surrogate --run $(1) --from-simulations bbd $($(3))
$(CALIB) invert --run $(1) --validate 4 --refine 2 $(LABSIM) $($(3))
$(CALIB) compare --run $(1) --set restitution=0.3 --repeats 8 $(LABSIM)
endef

hidden-effect: setup
	$(CALIB) synth-lab --out $(LAB)/lab --set static_friction=0.45 --set rolling_friction=0.15 \
		--set restitution=0.3 --set surface_energy=0.6 --hidden cohesion $(LABCOND)
	$(call lab_rev0,$(LAB),6)
	$(call lab_rev1,$(LAB),cohesion,REV1)
	$(CALIB) report --run $(LAB)

# The other labs share the hidden-effect lab's revision-0 Box-Behnken heaps (the same requests):
# where that run directory has finished them, they are copied, not recomputed (docs/campaigns.md)
control-lab hidden-wall hidden-floor: export CALIB_REUSE = $(LAB)

# The control: the same lab with nothing hidden (the truth lies inside the starting model).
# compare should flag no condition and diagnose find no significant effect (30 min on 2 cores with the
# hidden-effect run's revision-0 BBD heaps in its cache; ~37 min from nothing, an estimate)
CTRL   := sample_runs/control-lab
control-lab: setup
	$(CALIB) synth-lab --out $(CTRL)/lab --set static_friction=0.45 --set rolling_friction=0.15 \
		--set restitution=0.3 --set surface_energy=0 --hidden none $(LABCOND)
	$(call lab_rev0,$(CTRL),6)
	$(CALIB) report --run $(CTRL)

# A second hidden effect: a slippery floor and cylinder (wall friction 0.2 against the grains' 0.45;
# the starting model gives the walls the grains' friction): compare, diagnose ranks wall friction first,
# add it and recalibrate over the span diagnose stepped it (0.2-0.4), compare
# (31 min on 2 cores with the hidden-effect run's revision-0 BBD heaps cached, ~40 min from nothing;
# docs/tutorial-hidden-effect.md section 7)
WALL   := sample_runs/hidden-wall
WREV1  := -s 'bbd.factors=["static_friction","rolling_friction","wall_static_friction"]' \
          -s factors.wall_static_friction.low=0.2 -s factors.wall_static_friction.high=0.4
hidden-wall: setup
	$(CALIB) synth-lab --out $(WALL)/lab --set static_friction=0.45 --set rolling_friction=0.15 \
		--set restitution=0.3 --set surface_energy=0 --set wall_static_friction=0.2 --hidden wall_friction $(LABCOND)
	$(call lab_rev0,$(WALL),6)
	$(call lab_rev1,$(WALL),wall_friction,WREV1)
	$(CALIB) report --run $(WALL)

# A third hidden effect: a rough floor (rolling resistance 0.4 on the floor and cylinder against the
# grains' 0.15; the starting model gives the walls the grains' rolling friction): compare, diagnose, add
# it and recalibrate over 0.1-0.5 (its declared range less the end where grains never stop rolling on
# the floor), compare (39 min on 2 cores with the hidden-effect run's revision-0 BBD heaps cached, ~47 min
# from nothing; docs/tutorial-hidden-effect.md section 8)
FLOOR  := sample_runs/hidden-floor
FREV1  := -s 'bbd.factors=["static_friction","rolling_friction","wall_rolling_friction"]' \
          -s factors.wall_rolling_friction.low=0.1 -s factors.wall_rolling_friction.high=0.5
hidden-floor: setup
	$(CALIB) synth-lab --out $(FLOOR)/lab --set static_friction=0.45 --set rolling_friction=0.15 \
		--set restitution=0.3 --set surface_energy=0 --set wall_rolling_friction=0.4 --hidden wall_rolling $(LABCOND)
	$(call lab_rev0,$(FLOOR),6)
	$(call lab_rev1,$(FLOOR),wall_rolling,FREV1)
	$(CALIB) report --run $(FLOOR)

# The paper's own BBD design (Table 6, from its Tables 3 and 5) simulated with our kernel at the
# `default` preset: does the simulated heap respond like the paper's EDEM one? (~12 min on 2 cores)
DBBD   := sample_runs/default-bbd
default-bbd: setup
	$(call paper_screening,$(DBBD))
	$(CALIB) bbd design --run $(DBBD)
	$(CALIB) simulate-heap --run $(DBBD) --design $(DBBD)/bbd/design.parquet --preset default --workers 2
	$(CALIB) bbd analyze --run $(DBBD)
	$(CALIB) report --run $(DBBD)

# The same design with the surface-energy range halved (0.44-0.81 J/m2): how the order of
# influence changes when cohesion matters less (docs/physics.md; ~10 min on 2 cores)
DBBD2  := sample_runs/default-bbd-half-g
default-bbd-half-g: setup
	$(call paper_screening,$(DBBD2))
	$(CALIB) bbd design --run $(DBBD2) -s 'bbd.ranges.surface_energy=[0.4375,0.8125]'
	$(CALIB) simulate-heap --run $(DBBD2) --design $(DBBD2)/bbd/design.parquet --preset default --workers 2
	$(CALIB) bbd analyze --run $(DBBD2)
	$(CALIB) report --run $(DBBD2)

# the paper's screening on its tables, the BBD design, its heaps at a shear modulus (and options), the analysis
define default_bbd_at
$(call paper_screening,$(1))
$(CALIB) bbd design --run $(1)
$(CALIB) simulate-heap --run $(1) --design $(1)/bbd/design.parquet --preset default --workers 2 --shear-modulus $(2) $(3)
$(CALIB) bbd analyze --run $(1)
$(CALIB) report --run $(1)
endef

# The same design at a 100x stiffer shear modulus (500 MPa, grains and walls): the JKR work of
# separation falls as G^-2/3, so cohesion matters less (docs/physics.md, 'Stiffness'; ~100 min on 2 cores)
DBBD3  := sample_runs/default-bbd-stiff
default-bbd-stiff: setup
	$(call default_bbd_at,$(DBBD3),5e8)

# The same design at 50 and 150 MPa: where between 5 and 500 MPa the order of influence turns to the
# paper's (docs/physics.md, 'Stiffness'; ~26 and ~80 min on 2 cores). At 150 MPa, where rolling friction
# first comes first, two seeds a point: one would not resolve its lead over the 3.4 deg pile-to-pile scatter
DBBD50  := sample_runs/default-bbd-50mpa
DBBD150 := sample_runs/default-bbd-150mpa
default-bbd-50mpa: setup
	$(call default_bbd_at,$(DBBD50),5e7)
default-bbd-150mpa: setup
	$(call default_bbd_at,$(DBBD150),1.5e8,--repeats 2)

# The same design at 500 MPa with the floor and cylinder at fixed friction (static 0.5, rolling 0.1,
# a typical particle-steel/acrylic pair; the paper gives none) instead of the grains' own: with the
# grains' 0.112 the base of a heap slides on the floor (docs/physics.md, 'Wall friction'; ~85 min on 2 cores)
DBBD4  := sample_runs/default-bbd-walls
default-bbd-walls: setup
	$(call default_bbd_at,$(DBBD4),5e8,--set wall_static_friction=0.5 --set wall_rolling_friction=0.1)

# regenerate the shipped photographs: drawn heaps for the smoke chain, DEM heaps for make calibrate
# (the truth of each goes to a truth.toml beside them, which no stage reads)
sample-photos: setup
	$(PY) stages/sample_photos.py
	$(CALIB) synth-lab --out $(CDATA) --set static_friction=0.3 --set rolling_friction=0.12 \
		--set restitution=0.3 --set surface_energy=0.4 --hidden none \
		--sizes 4-5 --cylinders 40 --fills 75 --repeats 5 --preset default --workers 1 --seed 11

docs: setup
	$(VENV)/bin/typer calib_cli.cli utils docs --name calib --output docs/cli.md

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
