"""antalate's own udpm reader against liblcm on real multicast, in a private network namespace:
what either sends the other receives (fragmented messages included), hostile datagrams are dropped
and counted, the socket shares the port and is released on close, and another group is not heard."""

from __future__ import annotations

import json
import subprocess

from tests.netns import NetNamespace

GROUP_A = "udpm://239.255.76.67:7667?ttl=0"
GROUP_B = "udpm://239.255.76.99:7667?ttl=0"


def test_own_reader_and_liblcm_on_one_group(netns: NetNamespace) -> None:
    proc = netns.python(
        "-m", "tests.children.udpm_readers", GROUP_A, GROUP_B, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    r = json.loads(out.strip().splitlines()[-1])
    assert r["liblcm_to_own"] and r["exact_intact"], r  # small and liblcm-fragmented, to both readers
    assert r["old_small"], r
    assert r["regex_intact"], r
    assert r["own_to_liblcm"] == list(range(1, 51)) and r["own_hears_itself"], r
    assert r["alive_after_hostile"], (r, err)
    assert r["forged_fragments_reassembled_by_both"], r  # our fragment layout is liblcm's
    assert r["damaged"] == 9, r  # every hostile datagram counted, once
    assert "not LCM or are damaged" in err  # and said, at a limited rate
    assert r["elsewhere"] == 0, r  # bound to its group, as liblcm binds
    assert r["open_before_close"] == 3 and r["open_after_close"] == 0, r  # Bus.close() closes its socket
