"""Quick settings shared by tests whose subject is not the method they run."""

from scapo.methods import METHODS

#: ``--option`` arguments of ICP's registered quick options (3 iterations, one hypothesis set), for tests that
#: predict with ICP but are not about its accuracy: 0.3 s instead of ~5 s on the 12-view test split (the tables'
#: default search is tested in tests/test_icp.py and tests/test_bench.py)
QUICK_ICP = [a for k, v in METHODS.get("icp").quick_options.items() for a in ("--option", f"{k}={v}")]
