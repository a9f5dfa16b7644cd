"""``fiper bag recover`` on the files a crash leaves (docs/bags.md, "What survives which stop"): a live bag
written by the project's writer in a process killed by SIGKILL (every closed chunk on disk, no summary, no
metadata.yaml), and the states a power cut can leave of such a file, approximated on it: the tail cut at any
byte, a tail of zeros (a file extended whose blocks never reached the disk), a last chunk whose body is zeros,
a changed byte, bytes that are no record. Recovery keeps every intact chunk before the damage, message for
message, and says where it stopped."""
from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from helpers.bag_damage import CHUNK, LIVE_INFO, chunk_messages, live_stream, mcap_of, records
from helpers.dds import allocate_domain, run_python

from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.recover import recover_bag, unfinished
from fiper_ros.cli import main

CHUNKS = 4


def _killed_writer(bag: Path, chunks: int) -> list[tuple[str, bytes]]:
    """The bag of :func:`helpers.bag_damage.write_and_die` (its process SIGKILLed) and the messages written."""
    with allocate_domain() as domain:  # no DDS traffic: the child process only writes a file
        code = f"from helpers.bag_damage import write_and_die; write_and_die({str(bag)!r}, {chunks})"
        done = run_python(["-c", code], domain, timeout=120)
    assert done.returncode == -9, done.stdout
    return [(topic, raw) for topic, _, raw in live_stream(chunks)]


@pytest.fixture(scope="module")
def killed_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[str, bytes]]]:
    """A bag of 4 closed chunks whose writer died, and what it was given; copy it before changing it."""
    bag = tmp_path_factory.mktemp("killed") / "killed"
    return bag, _killed_writer(bag, CHUNKS)


@pytest.fixture
def killed(killed_bag: tuple[Path, list[tuple[str, bytes]]], tmp_path: Path) -> tuple[Path, list[tuple[str, bytes]]]:
    """A copy of ``killed_bag``."""
    bag = tmp_path / "killed"
    shutil.copytree(killed_bag[0], bag)
    return bag, killed_bag[1]


def _read(bag: Path) -> list[tuple[str, bytes]]:
    with BagReader(bag) as reader:
        return [(m.topic, m.raw) for m in reader.messages()]


def test_a_killed_live_bag_recovers_every_closed_chunk(killed: tuple[Path, list[tuple[str, bytes]]], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    bag, written = killed
    assert sorted(p.name for p in bag.iterdir()) == ["killed.mcap"]
    data = mcap_of(bag).read_bytes()
    counts = chunk_messages(data)
    assert counts == [11, 10, 10, 10] and len(written) == sum(counts) + 4  # two steps died in the open chunk
    for position, opcode, _ in records(data):  # every chunk has the writer's CRC-32
        if opcode == CHUNK:
            assert int.from_bytes(data[position + 9 + 24:position + 9 + 28], "little") != 0
    assert main(["bag", "recover", str(bag), "-o", str(tmp_path / "copy")]) == 0
    assert unfinished(bag) and _read(tmp_path / "copy") == written[:41]  # -o leaves the bag as it was
    assert main(["bag", "recover", str(bag)]) == 0  # in place
    out = capsys.readouterr().out.splitlines()
    assert out[-3].startswith(f"{bag}: MCAP data but no metadata.yaml") and "after 4 complete chunk(s)" in out[-3]
    assert out[-2] == ("  kept 4 complete chunk(s), 41 messages: /fiper/action_chunks 20, "
                       "/fiper/observation_embedding 20, /fiper/rollout_events 1")
    assert out[-1] == f"  {bag}: finished (summary and metadata.yaml written)"
    assert sorted(p.name for p in bag.iterdir()) == ["killed.mcap", "metadata.yaml"]
    assert _read(bag) == written[:41]
    with BagReader(bag) as reader:  # the custom_data the recorder wrote beside its chunks
        assert reader.info == LIVE_INFO
    assert main(["bag", "recover", str(bag)]) == 0
    assert capsys.readouterr().out == f"{bag}: a finished bag, nothing to recover\n"


def _spans(data: bytes) -> list[tuple[int, int]]:
    return [(position, end) for position, opcode, end in records(data) if opcode == CHUNK]


def _zeroed(data: bytes, start: int, end: int) -> bytes:
    return data[:start] + bytes(end - start) + data[end:]


def _flipped(data: bytes, at: int) -> bytes:
    return data[:at] + bytes([data[at] ^ 1]) + data[at + 1:]


#: What a power cut can leave of the killed recorder's file (its chunk spans given) -> (that file, intact chunks).
POWER_CUTS: dict[str, Callable[[bytes, list[tuple[int, int]]], tuple[bytes, int]]] = {
    "cut 1 byte into the last chunk": lambda d, s: (d[:s[-1][0] + 1], 3),
    "cut inside the last chunk's head": lambda d, s: (d[:s[-1][0] + 9], 3),
    "cut inside the last chunk's fields": lambda d, s: (d[:s[-1][0] + 40], 3),
    "cut in the middle of the last chunk": lambda d, s: (d[:(s[-1][0] + s[-1][1]) // 2], 3),
    "cut 1 byte before the end of the last chunk": lambda d, s: (d[:s[-1][1] - 1], 3),
    "cut right after the last chunk": lambda d, s: (d[:s[-1][1]], 4),
    "zeros after the last chunk": lambda d, s: (d[:s[-1][1]] + bytes(4096), 4),
    "zeros from inside the third chunk on": lambda d, s: (_zeroed(d, s[2][0] + 100, len(d)), 2),
    "the last chunk's body zeros": lambda d, s: (_zeroed(d, s[-1][0] + 9, s[-1][1]), 3),
    "a changed byte in the last chunk": lambda d, s: (_flipped(d, s[-1][1] - 100), 3),
    "bytes that are no record after the last chunk": lambda d, s: (d[:s[-1][1]] + b"\x42" * 50, 4),
}


@pytest.mark.parametrize("cut", POWER_CUTS)
def test_what_a_power_cut_leaves_recovers_every_intact_chunk_before_it(
        cut: str, killed: tuple[Path, list[tuple[str, bytes]]], tmp_path: Path) -> None:
    bag, written = killed
    data = mcap_of(bag).read_bytes()
    counts = chunk_messages(data)
    damaged, intact = POWER_CUTS[cut](data, _spans(data))
    mcap_of(bag).write_bytes(damaged)
    recovery = recover_bag(bag, tmp_path / "recovered")
    assert recovery.chunks == intact, recovery.where()
    assert _read(tmp_path / "recovered") == written[:sum(counts[:intact])]
    if intact < CHUNKS:
        assert f"after {intact} complete chunk(s)" in recovery.where()


def test_a_bag_without_a_complete_chunk_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "early"
    _killed_writer(bag, chunks=0)
    assert main(["bag", "recover", str(bag)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fiper bag recover: {bag}: MCAP data but no metadata.yaml") and err.endswith(
        "after 0 complete chunk(s)): the recording did not finish, or the file was cut: no complete chunk, "
        "nothing to read\n"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["early"]  # nothing of the attempt left
