# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""``astroalign_nd.conf``: the thread count and the compiled loops, set once."""

import os
import subprocess
import sys

import numpy as np
import pytest
from astropy.config import ConfigNamespace

import astroalign_nd
from astroalign_nd import _kernels, _pools, conf, find_transform
from astroalign_nd._settings import Conf
from astroalign_nd.batch import runners
from astroalign_nd.batch.runners import _init_worker
from astroalign_nd.simulate import simulate_pair

from _helpers import frame_error

WORKTREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_conf_is_an_astropy_config_namespace():
    assert isinstance(astroalign_nd.conf, ConfigNamespace)
    assert "conf" in dir(astroalign_nd)
    assert Conf.num_threads.defaultvalue == 0 and Conf.use_compiled.defaultvalue is True


def test_num_threads_from_conf(monkeypatch):
    monkeypatch.setattr(_kernels, "_ENV_NUM_THREADS", "")
    with conf.set_temp("num_threads", 3):
        assert _kernels.num_threads() == 3
        calls = _kernels.run_split(lambda start, stop: (start, stop), 9, ())
        assert calls == [(0, 3), (3, 6), (6, 9)]  # three chunks: three threads
    assert _kernels.num_threads() >= 1  # 0: every CPU
    monkeypatch.setattr(_kernels, "_ENV_NUM_THREADS", "2")
    assert _kernels.num_threads() == 2  # the environment, when conf says 0
    with conf.set_temp("num_threads", 1):
        assert _kernels.num_threads() == 1  # conf, when set, wins


def test_bad_num_threads_is_explained():
    pts = np.random.default_rng(0).uniform(0, 100, (20, 2))
    with conf.set_temp("num_threads", -2):
        with pytest.raises(ValueError, match=r"conf\.num_threads .* got -2"):
            find_transform(pts, pts + 1)
    with pytest.raises(TypeError):
        conf.num_threads = "many"


def test_environment_variable_still_works():
    code = ("from astroalign_nd import _kernels, conf; print(_kernels.num_threads()); "
            "conf.num_threads = 1; print(_kernels.num_threads())")
    env = dict(os.environ, ASTROALIGN_ND_NUM_THREADS="5", PYTHONPATH=WORKTREE)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["5", "1"]
    env["ASTROALIGN_ND_NUM_THREADS"] = "zero"
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True)
    assert res.returncode != 0 and "ASTROALIGN_ND_NUM_THREADS must be a positive" in res.stderr


def test_numpy_loops_give_the_same_transform():
    pair = simulate_pair((256, 256), n_stars=100, rotation=25.0, seed=4)
    compiled, _ = find_transform(pair.source, pair.target)
    with conf.set_temp("use_compiled", False):
        assert not _kernels._compiled()
        numpy_only, _ = find_transform(pair.source, pair.target)
    assert _kernels._compiled() == _kernels.HAVE_COMPILED
    assert frame_error(numpy_only, pair.transform, (256, 256)) < 0.1
    assert frame_error(numpy_only, compiled, (256, 256)) < 1e-6


def test_batch_workers_share_the_cpus_unless_told(monkeypatch):
    # Not the worker's signal handlers and parent watch in the test process:
    # its children (the CLI tests' subprocesses) would inherit an ignored SIGINT.
    monkeypatch.setattr(_pools, "_worker_signals", lambda: None)
    monkeypatch.setattr(runners, "_WORKER_CONFIG", None)
    monkeypatch.setattr(_kernels, "_ENV_NUM_THREADS", "")
    with conf.set_temp("num_threads", 0):
        _init_worker(None, 2)
        assert conf.num_threads == 2
    with conf.set_temp("num_threads", 4):
        _init_worker(None, 2)
        assert conf.num_threads == 4  # the user's choice stands
    monkeypatch.setattr(_kernels, "_ENV_NUM_THREADS", "3")
    with conf.set_temp("num_threads", 0):
        _init_worker(None, 2)
        assert conf.num_threads == 0 and _kernels.num_threads() == 3
