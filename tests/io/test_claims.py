"""Outputs claimed for a whole run (``claim_output``): two processes writing one path, a claim
left by a killed run, and the atomic commit that never replaces a file without ``overwrite``."""

import json
import os
import subprocess
import sys

import pytest

from jaxgeo.io._atomic import (
    CLAIM_SUFFIX,
    OutputClaimedError,
    atomic_output,
    claim_output,
)

HOLD = """
import sys, time
from jaxgeo.io._atomic import claim_output
claim = claim_output(sys.argv[1], "holder")
print("claimed", flush=True)
time.sleep(60)
"""


@pytest.fixture
def holder(tmp_path):
    """A second process holding the claim of ``tmp_path/out.tif``."""
    out = tmp_path / "out.tif"
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE,
                            text=True)  # fmt: skip
    try:
        assert proc.stdout.readline().strip() == "claimed"
        yield out, proc
    finally:
        proc.kill()
        proc.wait()


def test_a_second_process_is_refused_naming_the_first(holder):
    out, proc = holder
    with pytest.raises(OutputClaimedError) as err:
        claim_output(out, "jaxgeo ortho x.tif -o out.tif")
    message = str(err.value)
    assert str(out) in message and f"pid {proc.pid}" in message and "'holder'" in message
    assert isinstance(err.value, FileExistsError)  # what the commands report as exit 2
    assert not out.exists()


def test_with_overwrite_it_runs_and_says_that_the_last_wins(holder):
    out, proc = holder
    claim = claim_output(out, "mine", overwrite=True)
    assert claim.file is None and f"pid {proc.pid}" in claim.note and "ends last" in claim.note
    claim.release()  # releases nothing: the other run's claim stays
    assert json.loads((out.parent / (out.name + CLAIM_SUFFIX)).read_text())["pid"] == proc.pid


def test_the_claim_of_a_killed_run_is_taken_over_with_a_note(holder):
    out, proc = holder
    proc.kill()
    proc.wait()
    claim = claim_output(out, "mine")
    assert claim.file is not None and "no longer runs" in claim.note and str(proc.pid) in claim.note
    assert json.loads(claim.file.read_text())["command"] == "mine"
    claim.release()
    assert not claim.file.exists()


def test_a_claim_is_released_only_by_its_owner(tmp_path):
    out = tmp_path / "o.csv"
    first = claim_output(out, "first")
    assert first.note == "" and first.file.name == "o.csv" + CLAIM_SUFFIX
    with pytest.raises(OutputClaimedError):  # this very process, a second claim: refused too
        claim_output(out, "second")
    first.release()
    second = claim_output(out, "second")
    first.release()  # a stale handle removes nothing
    assert second.file.exists()
    second.release()
    assert list(tmp_path.iterdir()) == []


def test_a_folder_yet_to_be_made_is_claimed_beside_its_first_existing_parent(tmp_path):
    claim = claim_output(tmp_path / "a" / "b" / "out", "x")
    assert claim.file == tmp_path / ("a" + CLAIM_SUFFIX)
    claim.release()
    assert list(tmp_path.iterdir()) == []


def test_the_commit_refuses_a_file_another_writer_made_meanwhile(tmp_path):
    out = tmp_path / "o.txt"
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        with atomic_output(out) as tmp:
            tmp.write_text("mine")
            out.write_text("theirs")  # made after the check at the start
    assert out.read_text() == "theirs" and sorted(p.name for p in tmp_path.iterdir()) == ["o.txt"]
    with atomic_output(out, overwrite=True) as tmp:
        tmp.write_text("mine")
    assert out.read_text() == "mine"


def test_two_writers_at_once_one_claim(tmp_path):
    """Four processes started together: exactly one gets the claim."""
    code = ("import sys; from jaxgeo.io._atomic import claim_output, OutputClaimedError\n"
            "try:\n    claim_output(sys.argv[1], 'p'); print('won')\n"
            "except OutputClaimedError: print('lost')\n")  # fmt: skip
    out = tmp_path / "same.tif"
    env = {**os.environ, "JAXGEO_CACHE_DIR": "off"}
    procs = [subprocess.Popen([sys.executable, "-c", code, str(out)], stdout=subprocess.PIPE,
                              text=True, env=env) for _ in range(4)]  # fmt: skip
    said = [p.communicate(timeout=120)[0].strip() for p in procs]
    assert said.count("won") == 1 and said.count("lost") == 3, said
