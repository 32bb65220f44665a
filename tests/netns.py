"""Where tests imported the namespace and process helpers from before tests/harness/ gathered them;
the same names, still importable from here."""

from tests import REPO as REPO
from tests.harness.netns import NetNamespace as NetNamespace
from tests.harness.netns import netns_unavailable as netns_unavailable
from tests.harness.process import child_env as child_env
from tests.harness.process import group_members as group_members
from tests.harness.process import stop_process as stop_process
