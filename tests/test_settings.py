import pytest

from calib_cli.errors import CalibError
from calib_cli.settings import factor_space, load_settings, parse_overrides


def test_defaults_are_the_paper_setup():
    s = load_settings()
    sp = factor_space(s, s["pb"]["factors"])
    assert sp.names == ["static_friction", "rolling_friction", "surface_energy", "restitution"]
    assert (sp["static_friction"].low, sp["static_friction"].high) == (0.05, 0.5)
    assert (sp["surface_energy"].unit, sp["surface_energy"].high) == ("J/m2", 2.0)
    assert s["target"] == 32.07 and s["response"] == "repose_angle"


def test_paper_toml_loads(tmp_path):
    from conftest import SETTINGS_DIR

    s = load_settings([SETTINGS_DIR / "paper.toml"])
    assert s["ascent"]["method"] == "diagonal" and s["bbd"]["fixed"] == {"restitution": 0.2}


def test_overrides_parse_types():
    assert parse_overrides(["pb.alpha=0.1", "ascent.method=diagonal", "bbd.factors=['a','b']"]) == {
        "pb": {"alpha": 0.1}, "ascent": {"method": "diagonal"}, "bbd": {"factors": ["a", "b"]}}
    s = load_settings(overrides=["factors.restitution.low=0.15", "bbd.fixed.restitution=0.2"])
    assert s["factors"]["restitution"]["low"] == 0.15 and s["factors"]["restitution"]["high"] == 0.4


@pytest.mark.parametrize("bad", ["pb.alfa=0.1", "nonsense=1", "pb.alpha=2", "ascent.method=zigzag",
                                 "ascent.steps=2", "factors.restitution.low=0.9", "noequals", "heap.modulus=1e8",
                                 "heap.shear_modulus='stiff'", "heap.shear_modulus=true", "heap.preset=3", "heap=5",
                                 "heap.precision='single'", "heap.precision=32", "heap.engine='bogus'", "heap.engine=gpu2", "heap.engine='lammps'",
                                 "pb=1",
                                 # exit 70 before (a table for one value, no model, a model twice, sizes that
                                 # fill the memory): a helper's review, 2026-12-07
                                 "invert.population={a=1}", "invert.tolerance={}", "response={a='x'}",
                                 "pb.runs={a=1}", "surrogate.models=[]", "surrogate.models=['rsm','rsm']",
                                 "invert.samples=2147483648", "invert.population=1000000000000",
                                 "invert.restarts=100000", "invert.generations=10000000"])
def test_bad_settings_are_one_line_errors(bad):
    with pytest.raises(CalibError) as e:
        load_settings(overrides=[bad])
    assert "\n" not in str(e.value)


def test_heap_setup_of_a_run_is_a_setting_the_options_override():
    """[heap] preset / shear_modulus: the run's heaps; an option wins; the preset's own modulus is
    no modulus (the heaps' cache keys and the stages' hashes stay those of a run that named none)."""
    from calib_cli.heaps.inputs import heap_setup

    assert load_settings()["heap"] == {"preset": "default", "shear_modulus": None, "engine": "builtin",
                                       "precision": "double"}
    stiff = load_settings(overrides=["heap.shear_modulus=1.5e8", "heap.preset='smoke'"])
    assert heap_setup(load_settings(), None, None) == ("default", None)
    assert heap_setup(stiff, None, None) == ("smoke", 1.5e8)
    assert heap_setup(stiff, "default", 5e7) == ("default", 5e7)
    assert heap_setup(load_settings(overrides=["heap.shear_modulus=5000000"]), None, None) == ("default", None)
    for bad, needle in [(["heap.preset='huge'"], "unknown preset"), (["heap.shear_modulus=0"], "outside")]:
        with pytest.raises(CalibError, match=needle):
            heap_setup(load_settings(overrides=bad), None, None)


def test_bad_toml_file(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("this is = = not toml")
    with pytest.raises(CalibError, match="not valid TOML"):
        load_settings([p])
    with pytest.raises(CalibError, match="not found"):
        load_settings([tmp_path / "missing.toml"])


def test_overrides_from_python_are_a_mapping_or_one_string_and_a_clash_is_one_line(tmp_path):
    """docs/library.md: a KEY=VALUE option takes a dict from Python; one string is one pair, not its letters."""
    from calib_cli.heaps.inputs import given_pairs
    from calib_cli.stages.run_dir import init_run

    assert parse_overrides({"heap.shear_modulus": 1.5e8, "target": 33}) == {"heap": {"shear_modulus": 1.5e8},
                                                                            "target": 33}
    assert parse_overrides("pb.alpha=0.1") == {"pb": {"alpha": 0.1}}
    assert given_pairs("static_friction=0.3", "--set") == {"static_friction": 0.3}
    with pytest.raises(CalibError, match="target is a value, not a table"):  # was an AttributeError: exit 70
        parse_overrides(["target=30", "target.x=2"])
    init_run(tmp_path / "run", setting={"heap.shear_modulus": 1.5e8})
    assert load_settings([tmp_path / "run" / "settings.toml"])["heap"]["shear_modulus"] == 1.5e8
