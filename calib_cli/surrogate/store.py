"""A run's fitted surrogates on disk (RUN/surrogate/: each model's state, and which predicts held-out
heaps best), read back by invert and predict (paper 3.4-3.5)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from .. import artifacts as art
from ..errors import CalibError
from .models import model_from_state

MODELS_DIR = Path("surrogate") / "models"


def load_models(run: Path, model: Optional[str]) -> tuple[dict, dict]:
    """The fitted surrogates (``model``: that one only) by name, and best.json (which is best, its inputs and box)."""
    best_path = run / "surrogate" / "best.json"
    if not best_path.is_file():
        raise CalibError(f"no fitted surrogate in {run}: run `calib fit-surrogate --run {run}` first")
    best = art.read_json(best_path)
    names = [model] if model else [p.stem for p in sorted((run / MODELS_DIR).glob("*.json"))]
    models = {}
    for n in names:
        p = run / MODELS_DIR / f"{n}.json"
        if not p.is_file():
            raise CalibError(f"surrogate {n!r} was not fitted in {run} (have: "
                             f"{', '.join(q.stem for q in (run / MODELS_DIR).glob('*.json'))})")
        try:
            models[n] = model_from_state(art.read_json(p))
            models[n].predict(np.zeros((1, len(models[n].inputs))))  # a network's weights of the wrong size fail here
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, RuntimeError) as e:  # edited or truncated
            raise CalibError(f"surrogate file {p} is not one `calib fit-surrogate` writes ({type(e).__name__}: {e}); "
                             f"fit it again: `calib fit-surrogate --run {run} --force`") from None
    return models, best


