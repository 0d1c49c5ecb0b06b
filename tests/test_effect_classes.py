"""Everything an effect needs lives on its two classes (``docs/adding-an-effect.md``): these checks run
over the registries, so a new effect is checked as soon as both twins are registered."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo_gym.collect import collect
from aibo_gym.effects import EFFECTS
from aibo_gym.envs import AiboBeaconsEnv
from learners.arrays.batch import make_batch
from learners.model.effects import EFFECT_MODELS, EffectModel, effect_from_json
from learners.model.model import start_model

NAMES = sorted(EFFECT_MODELS)


@pytest.fixture(scope="module")
def batch():
    return make_batch([collect(None, 600, seed=5)])


@pytest.mark.parametrize("name", NAMES)
def test_the_example_is_a_valid_parameter_set_of_both_twins(name):
    cls = EFFECT_MODELS[name]
    assert set(cls.EXAMPLE) == set(cls.PARAMS), f"{name}: EXAMPLE must give every parameter"
    for key, value in cls.EXAMPLE.items():
        assert cls.PARAMS[key].domain_error(np.asarray(value, dtype=float)) == "", (name, key)
    sim = {k: np.asarray(v).tolist() for k, v in cls.EXAMPLE.items()}
    env = AiboBeaconsEnv({"effects": {name: sim}})  # the simulator twin accepts it (one-line error otherwise)
    assert env.config["effects"][name] == sim
    assert name in EFFECTS and sorted(EFFECTS[name].defaults) == sorted(cls.PARAMS)


@pytest.mark.parametrize("name", NAMES)
def test_the_simulator_twin_accepts_every_value_the_learner_twin_can_fit(name):
    """A diagnosed model is replayed by its calibrated simulator (``experiments.calibrated``): a fitted value inside
    the learner twin's bounds that the simulator twin refused made every replica fail (MRCLAM robot 5: the search's
    ``velocity_fade`` at -0.0075/min, a speed that grows, against the simulator's [0, inf])."""
    cls = EFFECT_MODELS[name]
    for key, param in cls.PARAMS.items():
        lo, hi = EFFECTS[name].bounds.get(key, (-np.inf, np.inf))
        assert lo <= param.low and param.high <= hi, (name, key, (param.low, param.high), (lo, hi))


@pytest.mark.parametrize("name", NAMES)
def test_the_example_lowers_into_a_model(name, batch):
    cls = EFFECT_MODELS[name]
    effect = cls.start(batch).with_values(**cls.EXAMPLE)
    for key, value in cls.EXAMPLE.items():
        np.testing.assert_allclose(effect.values()[key], value)
    lo = start_model(batch, 1 / 30, "height_px", 40).with_effect(effect).lower(batch)
    arrays = [v for v in vars(lo).values() if isinstance(v, np.ndarray) and v.dtype.kind == "f"]
    assert arrays and all(np.all(np.isfinite(a)) for a in arrays)


@pytest.mark.parametrize("name", NAMES)
def test_the_example_round_trips_through_the_model_file_entry(name, batch):
    cls = EFFECT_MODELS[name]
    effect = cls.start(batch).with_values(**cls.EXAMPLE)
    doc = json.loads(json.dumps(effect.to_json()))
    back = effect_from_json(doc, "model.json")
    assert type(back) is cls
    for key, value in cls.EXAMPLE.items():
        np.testing.assert_allclose(back.values()[key], value)


@pytest.mark.parametrize("name", NAMES)
def test_probe_and_remedy_name_the_effects_own_parameters(name):
    cls = EFFECT_MODELS[name]
    assert set(cls.PROBE) <= set(cls.PARAMS), name
    assert not (cls.PROBE and cls.GRID), f"{name}: a grid parameter is probed by its own profile"
    for key, step in cls.PROBE.items():
        assert np.shape(step) == np.shape(cls.EXAMPLE[key]) and np.any(np.asarray(step) != 0), (name, key)
    assert isinstance(cls.REMEDY, str)


def test_the_search_reads_probe_and_remedy_from_the_classes():
    """No per-name tables left in the search: its probe and remedy come from ``EFFECT_MODELS``."""
    from learners.discrepancy import search

    assert not hasattr(search, "PROBE") and not hasattr(search, "REMEDY")
    assert "heading" in EFFECT_MODELS["angle_bias"].REMEDY and EFFECT_MODELS["angle_bias"].PROBE


def test_every_signature_names_a_statistic_the_check_computes(batch):
    """``SIGNATURE`` and ``ALSO_SIGNATURES`` are matched (as substrings) against the calibrated check's statistic names: one that
    matches none would never report the effect as unexplained. The model is fitted a few iterations: a start model
    commands no motion (every velocity 0), so a signature against the commanded turn rate has one bin; the log is long
    enough (3 minutes) for the signed timing signatures' 32 changes of the command."""
    from learners.discrepancy.statistics import check_statistics
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions

    tr = collect(None, 5400, seed=5)
    model = EMLearner(EMOptions(starts=1, max_iter=3, alias_search=False, lag_search=False)).fit([tr]).params
    names = list(check_statistics(model, [tr]))
    for name, cls in EFFECT_MODELS.items():
        for signature in cls.signatures():
            assert any(signature in n for n in names), (name, signature, names)


@pytest.mark.parametrize("module, registry", [("learners.model.effects", "EFFECT_MODELS"),
                                              ("learners.model.model", None), ("aibo_gym.effects", "EFFECTS")])
def test_the_registries_are_full_whichever_module_a_process_imports_first(module, registry):
    """The catalogues register from their packages' inits: a fresh process that imports one module sees every
    effect (a registry filled by an import at the bottom of some module is empty until that module is imported)."""
    import subprocess
    import sys

    want = sorted(EFFECT_MODELS) if registry != "EFFECTS" else sorted(EFFECTS)
    code = (f"import {module}\nfrom learners.model.effects import EFFECT_MODELS\nprint(sorted(EFFECT_MODELS))"
            if registry != "EFFECTS" else f"from {module} import {registry}\nprint(sorted({registry}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(want)


#: the effects whose class declares a reparameterization of the base model (``EffectModel.equivalent``)
REPARAMETERIZED = [n for n in NAMES if EFFECT_MODELS[n].equivalent is not EffectModel.equivalent]


@pytest.mark.parametrize("name", REPARAMETERIZED)
def test_an_equivalent_model_predicts_every_sighting_as_the_effect_does(name, batch):
    """``EffectModel.equivalent`` (a structural non-identifiability the search checks): where a class gives one,
    the model without the effect has the same filter log-likelihood as the model with its example values."""
    from learners.em.estep import e_step

    cls = EFFECT_MODELS[name]
    base = start_model(batch, 1 / 30, "height_px", 40)
    weights = np.random.default_rng(0).normal(0.0, [8.0, 3.0, 0.02], size=base.action.weights.shape)
    model = base.with_(action=base.action.with_values(weights=weights))
    model = model.with_effect(cls.start(batch).with_values(**cls.EXAMPLE))
    eq = model.effect(name).equivalent(model)
    assert eq is not None and eq.effect(name) is None
    with_it, without = e_step(model, batch, "compiled").loglik, e_step(eq, batch, "compiled").loglik
    plain = e_step(base.with_(action=model.action), batch, "compiled").loglik  # the effect dropped, nothing else
    assert abs(with_it - without) < 1e-9 * abs(with_it)
    assert abs(with_it - without) < 1e-6 * abs(with_it - plain)  # equal, where the effect alone moves it


def test_a_bearing_offset_is_identifiable_for_a_robot_that_cannot_move_sideways():
    from learners.model.action import ActionModel
    from learners.model.catalogue import AngleBias
    from learners.model.initial import DEFAULT_INITIAL
    from learners.model.model import Model

    action = ActionModel(np.array([[1.0, 0, 0], [0, 0, 0.01], [0, 0, 0], [0, 0, 0], [0, 0, 0]]) * 10, np.eye(3),
                         1 / 30, "unicycle", ("v", "omega"))
    model = Model(action, None, (DEFAULT_INITIAL,), (AngleBias(0.05),))
    assert AngleBias(0.05).equivalent(model) is None  # the turned weights would need a lateral column
    table = model.with_(action=ActionModel.zeros(40, 1 / 30))
    assert AngleBias(0.05).equivalent(table) is not None
