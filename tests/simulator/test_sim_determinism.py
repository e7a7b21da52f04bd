"""Same seed, same bytes of truth; another seed, another site."""

import hashlib

from simtest_support import short_run, truth_only_run

TRUTH_KEYS = ("dsm", "dem", "ortho", "mask", "mask_since_step1", "events")


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_same_seed_writes_identical_truth_files():
    a = short_run()  # with video surveys, 2 render workers
    b = truth_only_run(7)  # truth only, same seed
    compared = 0
    for step in (1, 2):
        ta, tb = a.step(step)["truth"], b.step(step)["truth"]
        assert set(ta) == set(tb)
        for key in TRUTH_KEYS:
            if key in ta:
                assert _sha(a.root / ta[key]) == _sha(b.root / tb[key]), (step, key)
                compared += 1
    for ra, rb in zip(a.data["registration"], b.data["registration"], strict=True):
        assert _sha(a.root / ra["shifted_dsm"]) == _sha(b.root / rb["shifted_dsm"])
        compared += 1
    assert compared == 3 + 6 + 4
    # The reported volumes are the same numbers too.
    ev_a = [e["depleted_m3"] for s in a.steps for e in s["events"]]
    ev_b = [e["depleted_m3"] for s in b.steps for e in s["events"]]
    assert ev_a == ev_b and len(ev_a) == 2


def test_another_seed_gives_another_site():
    a = truth_only_run(7)
    c = truth_only_run(8)
    assert _sha(a.truth(1, "dsm")) != _sha(c.truth(1, "dsm"))
    assert _sha(a.truth(2, "mask")) != _sha(c.truth(2, "mask"))
