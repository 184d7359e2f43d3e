"""What makes diagnose fast must not change its answers: the wall path-length cache and the parallel fits."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.diagnose.backend import CountFitter, FitTask
from estimator.model import MeasurementModel
from radseek.geometry import path_lengths
from radseek_io.dataset import read_dataset


def test_cached_wall_path_lengths_are_exact(shared_datasets):
    """The near-wall cache returns the model's (soft-edged) slab lengths to rounding, and those stay within a
    ramp width or two of the hard slabs (radseek.geometry.path_lengths)."""
    from estimator.model import WallAttenuation, _SlabFrame

    ds = read_dataset(shared_datasets / "lattice-wall")
    m = MeasurementModel(ds.scenario, ("wall_attenuation",))
    part = m._parts[0]
    exact = _SlabFrame(m._walls, WallAttenuation.EDGE_M)
    rng = np.random.default_rng(1)
    pos = ds.frames.positions
    for _ in range(30):
        src = np.array([rng.uniform(3, 7), rng.uniform(2, 6), 0.0])
        for sd in (0.0, 0.001, 0.05, 0.4):  # recorded, Jacobian step, pose offsets, beyond the cache margin
            p = pos + rng.normal(0, sd, pos.shape)
            cached = part._lengths(p, src, m._walls)
            np.testing.assert_allclose(cached, exact.lengths(p, src), rtol=1e-12, atol=1e-12)
            # two walls meet at a corner here: each may add its ramp
            assert np.abs(cached - path_lengths(p, src, m._walls)).max() < 2 * WallAttenuation.EDGE_M
    # vectorised hypotheses (P sources) bypass the cache
    srcs = np.array([[4.0, 4.0, 0.0], [6.0, 3.0, 0.0]])[:, None, :]
    np.testing.assert_allclose(part._lengths(pos, srcs, m._walls), exact.lengths(pos, srcs), atol=1e-12)


@pytest.mark.io
def test_parallel_candidate_fits_equal_serial_ones(shared_datasets):
    ds = read_dataset(shared_datasets / "lattice-clean")
    serial = CountFitter(ds.scenario, ds.frames, n_starts=1, quiet=True)
    base = serial.fit(())
    tasks = [FitTask(("dead_time",), dict(base.values), 1), FitTask(("air_attenuation",), dict(base.values), 1)]
    a, _ = serial.fit_many(tasks)
    par = CountFitter(ds.scenario, ds.frames, n_starts=1, quiet=True, jobs=2)
    b, side = par.fit_many(tasks, {"answer": lambda: 42})
    assert side == {"answer": 42}
    for x, y in zip(a, b, strict=True):
        assert x.nll == y.nll and x.values == y.values
    assert par._cache[("dead_time",)].nll == b[0].nll  # parallel results are cached in the parent


@pytest.mark.io
def test_a_batch_fit_does_not_depend_on_its_siblings(shared_datasets):
    """Two unmapped-wall candidates from different starts each fit their own inner model (without the wall) from
    their own start, whether the batch runs here or in workers: with --jobs 1 the second once took the first's
    cached inner fit, and the two settings named different effects on one flight."""
    ds = read_dataset(shared_datasets / "lattice-clean")
    serial = CountFitter(ds.scenario, ds.frames, n_starts=1, quiet=True)
    base = serial.fit(())
    far = {**base.values, "x": base.values["x"] + 1.5, "y": base.values["y"] - 1.0}
    tasks = [FitTask(("dead_time", "unmapped_wall"), dict(base.values), 1),
             FitTask(("dead_time", "unmapped_wall"), far, 1)]
    a, _ = serial.fit_many(tasks)
    alone = CountFitter(ds.scenario, ds.frames, n_starts=1, quiet=True)
    alone._cache = {(): base}
    second, _ = alone.fit_many(tasks[1:])
    assert a[1].nll == second[0].nll and a[1].values == second[0].values
    par = CountFitter(ds.scenario, ds.frames, n_starts=1, quiet=True, jobs=2)
    par._cache = {(): base}
    b, _ = par.fit_many(tasks)
    for x, y in zip(a, b, strict=True):
        assert x.nll == y.nll and x.values == y.values
    # the inner fits the tasks made are kept, the better of the two
    inner = serial._cache[("dead_time",)]
    assert inner.nll == par._cache[("dead_time",)].nll
