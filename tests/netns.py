"""Deprecated: import from ``tests.harness.netns`` and ``tests.harness.process``. Where tests imported these
names from before tests/harness/ gathered the helpers; they still work for one release (a behavior
package's tests may have copied the old path from docs/behaviors.md), with a DeprecationWarning that
names the new place."""

import warnings

from tests import REPO as REPO
from tests.harness.netns import NetNamespace as NetNamespace
from tests.harness.netns import netns_unavailable as netns_unavailable
from tests.harness.process import child_env as child_env
from tests.harness.process import group_members as group_members
from tests.harness.process import stop_process as stop_process

warnings.warn(
    "tests.netns is deprecated: import from tests.harness.netns and tests.harness.process",
    DeprecationWarning,
    stacklevel=2,
)
