"""Independent pre/post DSM pair generators for the detection benchmark.

Modules: `fields` (random fields, smoothing), `terrain`, `slides`, `surfaces`, `errors`
(the models) and `generators` (the registry that puts them together). None of them
uses the survey simulator (worker/simulator/).
"""

from worker.pairgen.generators import GENERATORS, PairGenerator, make_pair
from worker.pairgen.pair import DsmPair, SlideTruth

__all__ = ["GENERATORS", "DsmPair", "PairGenerator", "SlideTruth", "make_pair"]
