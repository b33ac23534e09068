# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The two detections of `register` run in two threads; their warning blocks
must neither leak a RuntimeWarning (CI, NumPy kernels) nor change the
caller's filters.
"""

import threading
import warnings

from astroalign_nd import conf, find_transform
from astroalign_nd.detection import daofind
from astroalign_nd.simulate import simulate_pair


def test_interleaved_warning_blocks_in_two_threads(monkeypatch):
    """Force the bad order: the first thread's block exits while the second's is open."""
    pair = simulate_pair((200, 200), n_stars=40, rotation=10.0, seed=2)
    main_in, side_in, main_out = (threading.Event() for _ in range(3))
    seen = set()
    real = daofind._daofind

    def interleaved(finder, data, mask):
        me = threading.get_ident()
        if me in seen:
            return real(finder, data, mask)
        seen.add(me)
        main = threading.current_thread() is threading.main_thread()
        if not main:
            main_in.wait(20)  # enter second: save the list that holds the first's filter
        # photutils' own pattern: ignore RuntimeWarning inside a block, then warn.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            if main:
                main_in.set()
                side_in.wait(20)
            else:
                side_in.set()
                main_out.wait(20)  # the first has restored the list it saved
                warnings.warn("Mean of empty slice", RuntimeWarning)  # as nanmean warns
        if main:
            main_out.set()
        return real(finder, data, mask)

    monkeypatch.setattr(daofind, "_daofind", interleaved)
    before = list(warnings.filters)
    with conf.set_temp("num_threads", 2):
        t, _ = find_transform(pair.source, pair.target)
    assert len(seen) == 2, "the two detections did not run in two threads"
    assert warnings.filters == before
    assert t.meta["quality"]["n_matches"] >= 10


def test_filters_restored_after_register():
    pair = simulate_pair((200, 200), n_stars=40, rotation=10.0, seed=3)
    before = list(warnings.filters)
    with conf.set_temp("num_threads", 2):
        find_transform(pair.source, pair.target)
    assert warnings.filters == before


def test_busy_cores_or_small_frames_detect_one_frame_after_the_other(monkeypatch):
    # With the default thread count, both frames are detected at once only
    # when a core is free (`core_to_spare`) and the frames are large enough
    # (`PARALLEL_DETECTION_PIXELS`); a thread count the user set is
    # followed.  The transform is the same either way, bit for bit.
    from astroalign_nd import _kernels, registration

    if _kernels.threads_chosen():
        import pytest

        pytest.skip("the environment sets the thread count")
    pair = simulate_pair((200, 200), n_stars=40, rotation=10.0, seed=4)
    with conf.set_temp("num_threads", 1):
        alone, _ = find_transform(pair.source, pair.target)
    used = []
    real = registration.side_pool

    def recorded():
        used.append(True)
        return real()

    monkeypatch.setattr(registration, "side_pool", recorded)
    monkeypatch.setattr(registration, "num_threads", lambda: 2)  # whatever this machine has
    cases = ((False, 0, 1, False), (True, 0, 1, True), (False, 2, 1, True),
             (True, 0, 200 * 200 + 1, False), (True, 2, 200 * 200 + 1, True))
    for spare, n_threads, min_pixels, side in cases:
        monkeypatch.setattr(registration, "core_to_spare", lambda spare=spare: spare)
        monkeypatch.setattr(registration, "PARALLEL_DETECTION_PIXELS", min_pixels)
        used.clear()
        with conf.set_temp("num_threads", n_threads):
            t, _ = find_transform(pair.source, pair.target)
        assert bool(used) is side, (spare, n_threads)
        assert (t.matrix == alone.matrix).all()
