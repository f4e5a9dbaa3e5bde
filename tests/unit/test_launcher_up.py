"""When a launcher's run counts from: every node answers and sees every other one alive."""

from hera.launcher import not_up

LOCAL = {"a", "b", "c"}


def st(*peers: str) -> dict:
    return {"peers": list(peers), "measures": {}}


def test_all_answering_and_linked_is_up():
    status = {n: st("a", "b", "c") for n in LOCAL}
    assert not_up(LOCAL, status) == {}


def test_a_silent_node_is_named():
    status = {"a": st("a", "b", "c"), "b": st("a", "b", "c")}
    assert not_up(LOCAL, status) == {"c": "does not answer"}


def test_answering_nodes_not_linked_yet_are_not_up():
    # b and c answer the launcher, but Zenoh has not linked them to each other yet
    status = {"a": st("a", "b", "c"), "b": st("a", "b"), "c": st("a", "c")}
    assert not_up(LOCAL, status) == {"b": "does not see c", "c": "does not see b"}


def test_nodes_of_other_hosts_are_not_waited_for():
    # hera up --only a,b: the spec's other nodes may start later elsewhere
    status = {"a": st("a", "b"), "b": st("b", "a"), "z": st("z")}
    assert not_up({"a", "b"}, status) == {}


def test_an_output_file_is_probed_without_touching_what_is_there(tmp_path):
    from hera.launcher import output_file_problems

    kept = tmp_path / "kept.mcap"
    kept.write_bytes(b"an earlier recording")
    assert output_file_problems("--mcap", kept) == []
    assert kept.read_bytes() == b"an earlier recording"  # not truncated
    assert output_file_problems("--mcap", tmp_path / "new.mcap") == []
    assert not (tmp_path / "new.mcap").exists()  # not left behind
    (tmp_path / "file").write_text("x")
    assert output_file_problems("--mcap", tmp_path / "file" / "o.mcap") == [
        f"--mcap: cannot write {tmp_path}/file/o.mcap: Not a directory"
    ]
    assert output_file_problems("--mcap", tmp_path) == [
        f"--mcap: cannot write {tmp_path}: Is a directory"
    ]
