"""Test configuration: hypothesis defaults shared by every test file (helpers live in strategies.py).

``HYPOTHESIS_PROFILE=thorough`` runs ten times more examples in the tests that use the default count.
"""

import os

from hypothesis import HealthCheck, settings

_COMMON = dict(
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    print_blob=True,
)
settings.register_profile("ringtrack", max_examples=50, **_COMMON)
settings.register_profile("thorough", max_examples=500, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ringtrack"))
