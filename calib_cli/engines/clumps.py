"""Multi-sphere grains (clumps) for the LAMMPS engine: the paper's four shapes (section 2.2.2,
Fig. 5: flattened, conical, block-like and spherical), each built from overlapping spheres
inscribed in the grain's bounding sphere.

A grain of diameter d (drawn uniform in the condition's 3-5 mm, as for spheres) is the clump
scaled to a bounding sphere of diameter d, so a clump replaces a sphere of the same lattice
fill without any initial overlap. The built-in kernel has spheres only; these shapes exist to
test whether particle shape is what makes the paper's heaps respond to rolling friction first
(docs/physics.md, "Particle shape").

Geometry (unit bounding radius; centres and radii of the sub-spheres):

* flattened: three spheres r = 0.55 in an equilateral triangle, centres 0.45 from its centroid
  (a disc 2 wide, 1.1 thick);
* conical: a base triangle of three spheres r = 0.5 (centres 0.46 out, 0.2 down) under an apex
  sphere r = 0.45 at 0.55 up;
* block-like: eight spheres r = 0.5 on the corners of a cube of half-edge 0.289 (centres 0.5
  from the middle): a rounded cube;
* spherical: one sphere r = 1.

The masses are the sub-spheres' with the density scaled so that each clump weighs rho times
the volume of the union of its spheres (overlaps counted once, by Monte Carlo); the moments of
inertia are LAMMPS's, from the sub-spheres (overlaps counted twice, a few per cent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import CalibError


@dataclass(frozen=True)
class Shape:
    name: str
    centres: np.ndarray  # (k, 3), unit bounding radius
    radii: np.ndarray  # (k,)

    @property
    def volume_fraction(self) -> float:
        """Volume of the union of the sub-spheres over their summed volume (<= 1)."""
        return _union_fraction(self.name)


def _triangle(c: float, z: float = 0.0) -> np.ndarray:
    a = np.deg2rad([90.0, 210.0, 330.0])
    return np.column_stack([c * np.cos(a), c * np.sin(a), np.full(3, z)])


_h = 0.5 / np.sqrt(3.0)
SHAPES: dict[str, Shape] = {
    "flattened": Shape("flattened", _triangle(0.45), np.full(3, 0.55)),
    "conical": Shape("conical", np.vstack([_triangle(np.sqrt(0.21), -0.2), [[0.0, 0.0, 0.55]]]),
                     np.array([0.5, 0.5, 0.5, 0.45])),
    "block": Shape("block", np.array([[x, y, z] for x in (-_h, _h) for y in (-_h, _h) for z in (-_h, _h)]),
                   np.full(8, 0.5)),
    "sphere": Shape("sphere", np.zeros((1, 3)), np.ones(1)),
}

#: the paper's mixture (section 2.2.2 builds all four; equal numbers of grains here)
PAPER_MIX = ("flattened", "conical", "block", "sphere")
SPHERES = ("sphere",)


def parse_shapes(text: str) -> tuple[str, ...]:
    """``sphere``, ``paper-mix`` or a comma-separated list of :data:`SHAPES`, as a canonical tuple:
    repeats dropped, and a list of spheres only is :data:`SPHERES` (the plain sphere run and its cache key)."""
    if text.strip() == "paper-mix":
        return PAPER_MIX
    names = tuple(dict.fromkeys(t.strip() for t in text.split(",") if t.strip()))
    bad = [n for n in names if n not in SHAPES]
    if bad or not names:
        raise CalibError(f"unknown shape(s) {bad or [text]}: sphere, paper-mix or a list of {', '.join(SHAPES)}")
    return names

_UNION: dict[str, float] = {}


def _union_fraction(name: str, n: int = 200_000) -> float:
    if name not in _UNION:
        s = SHAPES[name]
        rng = np.random.default_rng(0)
        p = rng.uniform(-1, 1, (n, 3))
        inside = np.zeros(n, bool)
        for c, r in zip(s.centres, s.radii):
            inside |= np.sum((p - c) ** 2, axis=1) <= r * r
        union = 8.0 * inside.mean()
        _UNION[name] = float(union / np.sum(4 / 3 * np.pi * s.radii**3))
    return _UNION[name]


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix uniform over SO(3) (from a random unit quaternion)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@dataclass
class ClumpFill:
    pos: np.ndarray  # (m, 3) sub-sphere centres
    rad: np.ndarray  # (m,)
    body: np.ndarray  # (m,) grain index, 0-based
    density: np.ndarray  # (m,) sub-sphere density giving each grain rho x its union volume
    shape: np.ndarray  # (n_grains,) shape name per grain


def clump_fill(pos: np.ndarray, rad: np.ndarray, rho: float, mix: tuple[str, ...], rng) -> ClumpFill:
    """Replace each sphere (centre, radius) of a fill by a randomly oriented clump inscribed in it,
    the shapes taken in turn from ``mix`` in random order."""
    n = len(rad)
    names = np.array([mix[i % len(mix)] for i in range(n)])
    rng.shuffle(names)
    P, R, B, D = [], [], [], []
    for i in range(n):
        s = SHAPES[names[i]]
        rot = random_rotation(rng)
        P.append(pos[i] + rad[i] * s.centres @ rot.T)
        R.append(rad[i] * s.radii)
        B.append(np.full(len(s.radii), i))
        D.append(np.full(len(s.radii), rho * s.volume_fraction))
    return ClumpFill(np.vstack(P), np.concatenate(R), np.concatenate(B), np.concatenate(D), names)
