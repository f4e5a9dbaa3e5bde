"""Security parts one by one: the secret, the certificates, the store, the args clock, the
CSV logger's bounds, names from the bus; and what Zenoh does with the generated settings
(two in-process sessions on loopback: authentication, access control, mutual TLS)."""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

import msgpack
import pytest
import zenoh
from cryptography import x509

from hera.args import ArgsStore
from hera.bus import BusConfig, open_session, tcp_endpoint
from hera.csvlog import CsvLog
from hera.datapath import REFUSED_ALARM, DataPath
from hera.keys import Keys
from hera.security.access import OPERATOR, access_control
from hera.security.certs import common_name, make_certs
from hera.security.credentials import Credentials, as_tls
from hera.security.secret import SecretError, make_secret, password, read_secret
from hera.store import Sample, Store
from hera.wire import Message, WireError, decode, encode


def msg(seq: int, inc: int = 0, t: float = 1.0) -> Message:
    return Message(seq, t, (1.0,), None, inc)


# -- store ---------------------------------------------------------------------------------
def test_a_forged_huge_seq_of_another_incarnation_cannot_freeze_a_source():
    s = Store()
    assert s.offer("a", "n1", msg(5, inc=7))
    assert s.offer("a", "n1", msg(2**63 - 1, inc=99))  # the forger's "incarnation"
    assert s.offer("a", "n1", msg(6, inc=7))  # the real producer goes on
    assert s.get_one("a", "n1").seq == 6
    assert s.offer_why("a", "n1", msg(6, inc=7)) == "stale"  # same incarnation: seq orders
    assert s.offer("a", "n1", msg(1, inc=8))  # a restart (new incarnation) is taken
    assert s.refused == {"stale": 1} and s.incarnations == 3


def test_a_bounded_store_refuses_strangers_and_names_over_quota_with_reasons():
    s = Store(nodes=["n1", "n2"], max_names_per_node=3)
    assert s.offer_why("obs9", "stranger", msg(1)) == "unknown_node"
    for i in range(3):
        assert s.offer(f"k{i}", "n1", msg(1))
    assert s.offer_why("k3", "n1", msg(1)) == "too_many_names"
    assert s.offer("k3", "n2", msg(1))  # another node's quota is its own
    assert s.offer("k0", "n1", msg(2))  # known sources go on
    assert s.refused == {"unknown_node": 1, "too_many_names": 1}
    assert len(s.snapshot()) == 4


def test_a_cursor_takes_a_new_incarnation_as_new():
    s = Store()
    cur = s.cursor(["a"])
    s.offer("a", "n1", msg(50, inc=1))
    assert [x.seq for x in cur.new()] == [50]
    s.offer("a", "n1", msg(1, inc=2))
    assert [x.seq for x in cur.new()] == [1]
    assert cur.new() == []


# -- wire ----------------------------------------------------------------------------------
def test_the_incarnation_travels_and_is_checked():
    assert decode(encode(3, 1.0, [1.0], inc=42)).inc == 42
    assert decode(msgpack.packb({"v": 1, "seq": 3, "t": 1.0, "val": [1.0]})).inc == 0
    for bad in (-1, 2**63, "x", True):
        with pytest.raises(WireError, match="inc must be"):
            decode(msgpack.packb({"v": 1, "seq": 3, "t": 1.0, "val": [1.0], "inc": bad}))


# -- names from the bus --------------------------------------------------------------------
@pytest.mark.parametrize("name", ["x" * 3000, "ob s", "\u00f1ode", "a*", ""])
def test_names_a_file_could_not_carry_are_refused_as_bad_keys(name):
    keys = Keys("c")
    dp = DataPath("n1", keys, Store())
    sample = type("S", (), {})()
    sample.key_expr = f"hera/c/data/{name}/n2"
    sample.payload = type("P", (), {"to_bytes": lambda self: encode(1, 1.0, [1.0])})()
    dp.on_data(sample)
    assert dp.rejected == {"bad_key": 1}
    assert len(dp.last_rejection) < 400


def test_a_declared_source_whose_samples_are_all_refused_is_reported():
    keys = Keys("c")
    dp = DataPath("n1", keys, Store(), declared=frozenset({("a", "n2")}))

    def put(seq: int, inc: int, node: str = "n2"):
        sample = type("S", (), {})()
        sample.key_expr = f"hera/c/data/a/{node}"
        sample.payload = type(
            "P", (), {"to_bytes": lambda self: encode(seq, 1.0, [1.0], inc=inc)}
        )()
        dp.on_data(sample)

    put(10**12, 5)  # held: incarnation 5 at a huge seq
    for seq in range(1, REFUSED_ALARM + 1):
        put(seq, 5)
    assert dp.refused_sources() == {"a/n2": {"refused": REFUSED_ALARM, "reason": "stale"}}
    put(1, 6)  # accepted again: no longer reported
    assert dp.refused_sources() == {}


# -- args ----------------------------------------------------------------------------------
def test_an_args_write_from_the_far_future_is_refused_and_counted(tmp_path):
    a = ArgsStore("n1", state_dir=tmp_path, max_skew_ns=10**9)
    assert a._merge("gain", 2**62, "evil", 9) == 0
    assert a.rejected == {"future": 1} and "gain" not in a
    ahead = time.time_ns() + 5 * 10**8  # a peer whose clock runs 0.5 s ahead: within skew
    assert a._merge("gain", ahead, "n2", 1) == 1
    a.put("gain", 2)  # a later write wins although our clock is behind the peer's stamp
    assert a.get("gain") == 2 and a.clock > ahead


def test_a_poisoned_state_file_entry_is_dropped_at_load(tmp_path):
    (tmp_path / "args.msgpack").write_bytes(
        msgpack.packb({"gain": [2**62, "evil", 9], "ok": [time.time_ns(), "n1", 1]})
    )
    a = ArgsStore("n1", state_dir=tmp_path)
    assert a.items() == {"ok": 1} and a.rejected == {"future": 1}


# -- CSV logger ----------------------------------------------------------------------------
def test_the_csv_logger_keeps_a_bounded_number_of_files_open_and_loses_no_row(tmp_path):
    log = CsvLog(tmp_path, max_open=3)
    for rnd in range(1, 4):
        for i in range(10):
            log.write(Sample(f"m{i}", "n1", rnd, 1.0, 0.0, 0.0, (float(i),)))
            assert log.open_files <= 3
    for i in range(10):
        lines = (tmp_path / "measures" / f"m{i}_n1.csv").read_text().splitlines()
        assert [ln.split(",")[0] for ln in lines] == ["1", "2", "3"]
    assert log.reopened > 0
    log.close()


# -- secret and certificates ---------------------------------------------------------------
def test_the_secret_is_private_and_passwords_differ_per_identity(tmp_path):
    path = make_secret(tmp_path / "secret")
    assert path.stat().st_mode & 0o777 == 0o600
    secret = read_secret(path)
    assert password(secret, "n1") != password(secret, "n2")
    os.chmod(path, 0o644)
    with pytest.raises(SecretError, match="readable by others"):
        read_secret(path)
    with pytest.raises(SecretError, match="cannot read"):
        read_secret(tmp_path / "none")


def test_certificates_name_the_identity_and_its_hosts(tmp_path):
    written = make_certs(tmp_path, "c", {"n1": ["10.1.0.2"], "r1": ["gw.example"], OPERATOR: []})
    assert [common_name(p) for p in written] == ["n1", "r1", OPERATOR]
    cert = x509.load_pem_x509_certificate((tmp_path / "n1.pem").read_bytes())
    sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "10.1.0.2" in [str(ip) for ip in sans.get_values_for_type(x509.IPAddress)]
    assert (tmp_path / "n1.key").stat().st_mode & 0o777 == 0o600
    ca = (tmp_path / "ca.pem").read_bytes()
    make_certs(tmp_path, "c", {"n2": []})  # more identities: the same CA
    assert (tmp_path / "ca.pem").read_bytes() == ca
    issuer = x509.load_pem_x509_certificate((tmp_path / "n2.pem").read_bytes()).issuer
    assert issuer == x509.load_pem_x509_certificate(ca).subject
    # a folder it makes is the owner's only; one of the user's keeps its mode (it chmodded
    # the current folder to 0700 for 'hera certs --out .')
    make_certs(tmp_path / "new", "c", {"n1": []})
    assert (tmp_path / "new").stat().st_mode & 0o777 == 0o700
    (tmp_path / "mine").mkdir(mode=0o755)
    os.chmod(tmp_path / "mine", 0o755)
    make_certs(tmp_path / "mine", "c", {"n1": []})
    assert (tmp_path / "mine").stat().st_mode & 0o777 == 0o755
    assert (tmp_path / "mine" / "ca.key").stat().st_mode & 0o777 == 0o600


# -- what Zenoh does with the settings (real sessions on loopback) -------------------------
def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _nodes_acl(tls: bool = False):
    return access_control("c", ["n1", "n2", "n3"], [OPERATOR], tls)


def _pair(creds_of, tls: bool = False):
    """Node n1 (listening, with the cluster's ACL) and a peer of it with ``creds_of``."""
    e1 = tcp_endpoint("127.0.0.1", _port())
    n1 = creds_of("n1").secure(BusConfig(listen=(e1,)), _nodes_acl(tls))
    return n1, (as_tls(e1) if tls else e1)


def _client(endpoint: str, creds: Credentials | None):
    cfg = BusConfig(listen=(), connect=(endpoint,), mode="client")
    return open_session(cfg if creds is None else creds.secure(cfg))


@pytest.mark.parametrize("tls", [False, True])
def test_a_nodes_identity_writes_only_its_own_keys_and_cannot_control(tmp_path, tls):
    if tls:
        make_certs(tmp_path, "c", {"n1": [], "n2": [], "n3": [], OPERATOR: []})

        def creds_of(who):
            return Credentials(who, tls_dir=tmp_path)
    else:
        secret = b"s" * 64
        known = ("n1", "n2", "n3", OPERATOR)

        def creds_of(who):
            return Credentials(who, secret=secret, known=known)

    cfg, endpoint = _pair(creds_of, tls)
    got: list[str] = []
    asked: list[str] = []
    with open_session(cfg) as n1:
        n1.declare_subscriber("hera/c/**", lambda s: got.append(str(s.key_expr)))

        def on_ctl(q):
            with q:
                asked.append(str(q.key_expr))
                q.reply(str(q.key_expr), "{}")

        n1.declare_queryable("hera/c/ctl/n1/*", on_ctl, complete=True)
        n2 = _client(endpoint, creds_of("n2"))
        try:
            time.sleep(0.3)
            n2.put("hera/c/data/obs1/n2", encode(1, 1.0, [1.0]))
            n2.put("hera/c/data/obs1/n3", encode(1, 1.0, [1.0]))
            n2.put("hera/c/args/calib/n2/nav", b"x")
            n2.put("hera/c/args/calib/n3/nav", b"x")
            n2.put("hera/c/args/gain", b"x")
            replies = [r for r in n2.get("hera/c/ctl/n1/shutdown", timeout=0.5) if r.ok]
            status = [r for r in n2.get("hera/c/ctl/n1/status", timeout=0.5) if r.ok]
            time.sleep(0.3)
        finally:
            n2.close()
        # the listener identifies the opener of the link in both modes (without TLS only it)
        assert sorted(got) == ["hera/c/args/calib/n2/nav", "hera/c/data/obs1/n2"]
        assert replies == [] and len(status) == 1
        assert asked == ["hera/c/ctl/n1/status"]
        op = _client(endpoint, creds_of(OPERATOR))
        try:
            assert len([r for r in op.get("hera/c/ctl/n1/shutdown", timeout=0.5) if r.ok]) == 1
        finally:
            op.close()
        # without credentials, with a guessed password or another CA: no link at all
        with pytest.raises(zenoh.ZError):
            _client(endpoint, None).close()
        if tls:
            other = tmp_path / "other"
            make_certs(other, "c", {"n2": []})
            with pytest.raises(zenoh.ZError):
                _client(endpoint, Credentials("n2", tls_dir=other)).close()
            with pytest.raises(zenoh.ZError):  # plain TCP to the same port
                _client("tcp/" + endpoint[4:], None).close()
        else:
            with pytest.raises(zenoh.ZError):
                _client(endpoint, Credentials("n2", secret=b"t" * 64)).close()


def test_the_dictionary_file_is_gone_once_the_session_is_open(tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    creds = Credentials("n1", secret=b"s" * 64, known=("n1", "n2"))
    with open_session(creds.secure(BusConfig(listen=(tcp_endpoint("127.0.0.1", _port()),)))):
        assert list(Path(tmp_path).iterdir()) == []


def test_acl_block_is_what_zenoh_accepts():
    """A config with the generated block opens (Zenoh refuses malformed ACL configs)."""
    cfg = zenoh.Config()
    cfg.insert_json5("access_control", json.dumps(_nodes_acl()))
    cfg.insert_json5("listen/endpoints", json.dumps([tcp_endpoint("127.0.0.1", _port())]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    zenoh.open(cfg).close()
