"""A peer dials an endpoint that did not answer again within about a second (CONNECT_RETRY).

Zenoh's default backoff (1 s doubling to 4 s) left a peer unlinked for 2.8-3.8 s after the
other side began listening 3.7 s late; a cluster then runs seconds without its links.
"""

import time

from hera.bus import CONNECT_RETRY, BusConfig, open_session, tcp_endpoint
from hera.ports import free_ports


def test_a_peer_that_starts_listening_late_is_dialled_again_within_the_retry_bound():
    pa, pb = free_ports("127.0.0.1", 2)
    dialer = BusConfig(
        listen=(tcp_endpoint("127.0.0.1", pa),), connect=(tcp_endpoint("127.0.0.1", pb),)
    )
    late = BusConfig(listen=(tcp_endpoint("127.0.0.1", pb),))  # it does not dial: only A can link
    with open_session(dialer):
        time.sleep(3.7)  # past the default's first retries, before its 4 s one
        with open_session(late) as b:
            t0 = time.monotonic()
            while not list(b.info.peers_zid()) and time.monotonic() - t0 < 6:
                time.sleep(0.01)
            linked = time.monotonic() - t0
    bound = CONNECT_RETRY["period_max_ms"] / 1000
    assert linked < 2 * bound, f"linked {linked:.2f} s after the peer began listening"
