"""The campaign storage (campaign/storage.py) on a folder and on an S3-compatible server (moto's, on loopback):
files and folders in and out, a result marker that is never seen half-written, inputs keyed by their content."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from advsim_ros.campaign.config import CampaignError
from advsim_ros.campaign.storage import MANIFEST_NAME, Storage, storage_uri
from advsim_ros.io.cache import content_digest


@pytest.fixture(params=["file", "s3"])
def storage(request: pytest.FixtureRequest, tmp_path: Path) -> Storage:
    if request.param == "file":
        return Storage((tmp_path / "storage").as_uri())
    bucket = request.getfixturevalue("s3_bucket")
    return Storage(f"{bucket}/campaign")


def _bag(folder: Path, text: str = "frames") -> Path:
    """A folder shaped like a rosbag2 bag: metadata and a data file one level down."""
    (folder / "data").mkdir(parents=True)
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (folder / "data" / "log_0.mcap").write_bytes(text.encode() * 1000)
    return folder


def test_files_and_folders_go_in_and_come_back_byte_for_byte(storage: Storage, tmp_path: Path) -> None:
    bag = _bag(tmp_path / "bag")
    assert not storage.exists("attacks/k")
    assert storage.files("attacks/k") == []
    storage.put_tree(bag, "attacks/k/adversarial", skip=("metadata.yaml",))
    storage.put_file(bag / "metadata.yaml", "attacks/k/adversarial/metadata.yaml")
    assert storage.exists("attacks/k")  # a folder of the storage (a prefix of an object store)
    assert storage.exists("attacks/k/adversarial/data/log_0.mcap")
    assert storage.files("attacks/k") == ["adversarial/data/log_0.mcap", "adversarial/metadata.yaml"]
    back = tmp_path / "back"
    storage.get_tree("attacks/k", back)
    assert (back / "adversarial" / "data" / "log_0.mcap").read_bytes() == (bag / "data" / "log_0.mcap").read_bytes()
    storage.get_file("attacks/k/adversarial/metadata.yaml", tmp_path / "one" / "metadata.yaml")
    assert (tmp_path / "one" / "metadata.yaml").read_text() == (bag / "metadata.yaml").read_text()
    size = sum(p.stat().st_size for p in bag.rglob("*") if p.is_file())
    assert storage.sent == size  # what this process moved, counted
    assert storage.received == 2 * size - (bag / "data" / "log_0.mcap").stat().st_size
    storage.remove("attacks/k/adversarial/data")
    assert storage.files("attacks/k") == ["adversarial/metadata.yaml"]
    storage.remove("attacks/k")
    assert not storage.exists("attacks/k")
    storage.remove("attacks/k")  # nothing there: nothing to do


def test_a_result_marker_is_never_read_half_written(storage: Storage) -> None:
    """One process writes job_result.json while another polls for it: whatever it reads is whole."""
    document = {"row": {"attack": "k"}, "curve": list(range(300_000))}  # ~2 MB of JSON
    reader = Storage(storage.uri)
    seen: list[object] = []
    done = threading.Event()

    def poll() -> None:
        while not done.is_set() or not seen:
            if reader.exists("attacks/k/job_result.json"):
                seen.append(json.loads(reader.read_bytes("attacks/k/job_result.json")))  # ValueError if torn

    thread = threading.Thread(target=poll)
    thread.start()
    try:
        for _ in range(3):
            storage.write_json("attacks/k/job_result.json", document)
    finally:
        done.set()
        thread.join(timeout=60)
    assert seen
    assert all(found == document for found in seen)
    local = storage.local_root
    if local is not None:  # written under a temporary name and renamed: nothing else left beside it
        assert sorted(p.name for p in (local / "attacks" / "k").iterdir()) == ["job_result.json"]


def test_inputs_are_keyed_by_their_content_uploaded_once_and_fetched_once_per_node(
    storage: Storage, tmp_path: Path
) -> None:
    bag = _bag(tmp_path / "one" / "log")
    same = _bag(tmp_path / "two" / "log")  # the same bag elsewhere on the driver
    other = _bag(tmp_path / "three" / "log", text="other frames")
    params = tmp_path / "stack.yaml"
    params.write_text("/**:\n  ros__parameters:\n    use_sim_time: true\n")
    reference = storage.put_input(bag)
    assert reference == {"digest": content_digest(bag), "name": "log"}
    sent = storage.sent
    assert storage.put_input(same) == reference  # already there: nothing sent
    assert storage.sent == sent
    assert storage.put_input(other)["digest"] != reference["digest"]
    assert storage.exists(f"inputs/{reference['digest']}/{MANIFEST_NAME}")
    node = Storage(storage.uri)  # a worker node, its own cache folder
    cache = tmp_path / "node_cache"
    fetched = node.fetch_input(reference, cache)
    assert fetched == cache / reference["digest"] / "log"
    assert content_digest(fetched) == reference["digest"]
    received = node.received
    assert node.fetch_input(reference, cache) == fetched  # cached on this node: not downloaded again
    assert node.received == received
    file_reference = storage.put_input(params)
    assert node.fetch_input(file_reference, cache).read_text() == params.read_text()


def test_an_input_that_changed_in_the_storage_is_refused(storage: Storage, tmp_path: Path) -> None:
    reference = storage.put_input(_bag(tmp_path / "log"))
    storage.write_bytes(f"inputs/{reference['digest']}/log/data/log_0.mcap", b"not what was uploaded")
    with pytest.raises(CampaignError, match="another content"):
        Storage(storage.uri).fetch_input(reference, tmp_path / "cache")
    with pytest.raises(CampaignError, match="not in the storage"):
        Storage(storage.uri).fetch_input({"digest": "0" * 32, "name": "log"}, tmp_path / "cache")
    assert not (tmp_path / "cache" / reference["digest"]).exists()  # nothing half-fetched left in the cache


def test_the_storage_uri_comes_from_the_command_line_else_the_config_else_is_outdir(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = tmp_path / "campaigns" / "campaign.yaml"
    config.parent.mkdir()
    config.write_text("scenarios: []\n")
    assert storage_uri(config, None) is None  # OUTDIR itself
    config.write_text("storage: s3://bucket/campaign\n")
    assert storage_uri(config, None) == "s3://bucket/campaign"
    config.write_text("storage: ../shared\n")  # a plain path: relative to the config's folder
    assert storage_uri(config, None) == (tmp_path / "shared").as_uri()
    monkeypatch.chdir(tmp_path / "campaigns")
    assert storage_uri(config, "elsewhere") == (tmp_path / "campaigns" / "elsewhere").as_uri()  # the working folder's
    assert storage_uri(config, "gs://b/p") == "gs://b/p"
    config.write_text("storage: [s3://bucket]\n")
    with pytest.raises(CampaignError, match="storage: expected a URI"):
        storage_uri(config, None)
    assert Storage((tmp_path / "x").as_uri()).local_root == tmp_path / "x"
    assert Storage(str(tmp_path / "x")).local_root == tmp_path / "x"


def test_a_running_attacks_journal_is_streamed_line_by_line_and_never_cut_mid_line(
    storage: Storage, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from advsim_ros.campaign import shipping
    from advsim_ros.ros.launcher import wait_for

    monkeypatch.setattr(shipping, "STREAM_S", 0.05)
    journal = tmp_path / "queries.jsonl"
    journal.write_bytes(b'{"header": 1}\n')  # what an earlier try left: already in the storage, not sent again
    streamer = shipping._Streamer(storage.uri, journal, "attacks/a/queries.jsonl")
    streamer.start()
    try:
        with journal.open("ab") as stream:
            stream.write(b'{"query_id": 0}\n{"query_id": 1, "cut')  # a line being written
            stream.flush()
            assert wait_for(lambda: storage.exists("attacks/a/queries.jsonl"), timeout=10)
            assert storage.read_bytes("attacks/a/queries.jsonl") == b'{"header": 1}\n{"query_id": 0}\n'
            stream.write(b'": 2}\n')
            stream.flush()
            expected = b'{"header": 1}\n{"query_id": 0}\n{"query_id": 1, "cut": 2}\n'
            assert wait_for(lambda: storage.read_bytes("attacks/a/queries.jsonl") == expected, timeout=10)
    finally:
        streamer.stop()
    assert not streamer.is_alive()
