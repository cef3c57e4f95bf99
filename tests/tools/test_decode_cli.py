"""cdro-decode, run as a user would run it."""
import json
import subprocess
import sys

from cdro_tools import codec


def run(*args, stdin=None):
    return subprocess.run([sys.executable, "-m", "cdro_tools.decode", *args], input=stdin, capture_output=True)


def test_decodes_a_capture_to_json_lines(tmp_path, golden_dir):
    vectors = json.loads((golden_dir / "vectors.json").read_text())
    path = tmp_path / "run.cdrocap"
    with codec.CaptureWriter(path, "test", created_unix_us=0) as writer:
        writer.write(codec.CaptureRecord(10, bytes.fromhex(vectors["frames"][1]["bytes"])[:-1]))
        writer.write(codec.CaptureRecord(20, b"\x13\x37"))
        writer.write(codec.CaptureRecord(30, bytes.fromhex(vectors["frames"][11]["bytes"])[:-1],
                                         codec.capture_file.FLAG_TO_DEVICE))
    result = run(str(path))
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in result.stdout.decode().splitlines()]
    assert [(line["direction"], line["result"], line.get("type")) for line in lines] == [
        ("rx", "ok", "RANGE"), ("rx", "cobs", None), ("tx", "ok", "SET_SCHEDULE")]
    assert lines[0]["fields"] == vectors["frames"][1]["fields"]
    counters = json.loads(result.stderr.decode().splitlines()[-1])
    assert counters["received"]["frames_ok"] == 1 and counters["received"]["cobs_errors"] == 1


def test_shows_odometry_records_in_their_place(tmp_path, golden_dir):
    vectors = json.loads((golden_dir / "vectors.json").read_text())
    path = tmp_path / "golden.cdrocap"
    path.write_bytes(bytes.fromhex(vectors["capture"]["bytes"]))
    result = run(str(path))
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in result.stdout.decode().splitlines()]
    assert [(line["direction"], line.get("type")) for line in lines] == [
        ("rx", "HELLO"), ("tx", "SET_SCHEDULE"), ("odometry", "ODOMETRY"), ("rx", None), ("host_event", None)]
    assert lines[4]["data"] == vectors["capture"]["host_event"]["data"]
    odometry = lines[2]
    assert odometry["result"] == "ok" and odometry["fields"] == vectors["capture"]["odometry"]["message"]
    assert odometry["host_time_us"] == vectors["capture"]["records"][2]["host_time_us"]
    stderr = [json.loads(line) for line in result.stderr.decode().splitlines()]
    assert stderr[0]["capture"]["odometry_records"] == 1 and stderr[0]["capture"]["format_version"] == 3
    assert stderr[0]["capture"]["host_event_records"] == 1
    assert stderr[-1]["received"]["frames_ok"] == 1  # the JSON was not fed to the frame decoder


def test_a_damaged_odometry_record_is_shown_with_its_reason(tmp_path):
    path = tmp_path / "bad.cdrocap"
    with codec.CaptureWriter(path, "test", created_unix_us=0) as writer:
        writer.write(codec.CaptureRecord(10, b"[1, 2", codec.capture_file.FLAG_ODOMETRY))
    result = run(str(path))
    assert result.returncode == 0, result.stderr
    line = json.loads(result.stdout.decode())
    assert line["result"] == "bad_odometry" and "not a JSON object" in line["reason"]


def test_a_version_1_capture_still_decodes(tmp_path, golden_dir):
    vectors = json.loads((golden_dir / "vectors.json").read_text())
    path = tmp_path / "old.cdrocap"
    path.write_bytes(bytes.fromhex(vectors["capture_v1"]["bytes"]))
    result = run(str(path))
    assert result.returncode == 0, result.stderr
    assert len(result.stdout.decode().splitlines()) == 3  # (the empty record carries no chunk)
    assert json.loads(result.stderr.decode().splitlines()[0])["capture"]["format_version"] == 1


def test_raw_stdin_summary(golden_dir):
    vectors = json.loads((golden_dir / "vectors.json").read_text())
    result = run("--raw", "-", "--summary", stdin=bytes.fromhex(vectors["stream"]["bytes"]))
    assert result.returncode == 0
    assert result.stdout == b""
    assert json.loads(result.stderr.decode().splitlines()[-1])["received"] == vectors["stream"]["counters"]


def test_rejects_a_file_that_is_not_a_capture(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("hello")
    result = run(str(path))
    assert result.returncode == 2
    assert b"not a CDRO capture file" in result.stderr


def test_help_has_an_example():
    result = run("--help")
    assert result.returncode == 0 and b"example" in result.stdout
