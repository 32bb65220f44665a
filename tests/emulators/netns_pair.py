"""Where the Tello tests imported the veth-joined namespace pair from before tests/harness/netns.py held
the one namespace class; the same names, still importable from here."""

from tests.harness.netns import NetnsPair as NetnsPair
from tests.harness.netns import netns_pair_unavailable as netns_pair_unavailable
