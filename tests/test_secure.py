"""Secure teams: certificates, mutual TLS on every link, access control by certificate name.

The process tests run a lockstep ``--secure`` team and let intruders publish well-formed requests,
replies, commands and a forged End every 10 ms while it runs: nothing of theirs may reach any robot
or the world (the run equals the engine and nobody counts a rejected message), whether they come
without TLS, with a certificate of another authority, or with a genuine certificate of another
participant.
"""

from __future__ import annotations

import datetime
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import serialization

from ringtrack.bus.config import BusConfig, BusError
from ringtrack.bus.keys import Keys, robot_name
from ringtrack.bus.security import (
    Security,
    SecurityError,
    access_policy,
    check_team,
    common_name,
    create_team,
    issue,
    load_team,
    team_names,
)
from ringtrack.tools.bench.bench import isolation_works
from ringtrack.tools.cli import main
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from tests.helpers import RINGTRACK, assert_equals_engine, scenario, start_spawn, stop_all, wait_for_steps

CONVERGED_AT = 712  # paper-stationary's worked example


@pytest.fixture(scope="module")
def team(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("secure") / "team"
    create_team(directory, 6)
    return directory


def ringtrack(*arguments: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """The command's result, with a console wide enough that tables are not wrapped."""
    return subprocess.run([*RINGTRACK, *arguments], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "COLUMNS": "200"})


def one_line_error(completed: subprocess.CompletedProcess[str]) -> str:
    lines = completed.stderr.strip().splitlines()
    assert completed.returncode == 2 and len(lines) == 1, completed.stderr
    return lines[0]


# ---------------------------------------------------------------------------------- certificates
@pytest.mark.processes  # the command line, as a user runs it
@pytest.mark.timeout(120)
def test_certs_makes_one_certificate_per_participant_private_keys_and_refuses_to_overwrite(tmp_path: Path) -> None:
    directory = tmp_path / "team"
    made = ringtrack("certs", str(directory), "--robots", "3", "--hosts", "10.0.0.1,robot-b.local")
    assert made.returncode == 0, made.stderr
    authority = x509.load_pem_x509_certificate((directory / "ca.pem").read_bytes())
    for name in ["world", "monitor", "fusion", "router", "r0", "r1", "r2"]:
        certificate = x509.load_pem_x509_certificate((directory / f"{name}.pem").read_bytes())
        assert common_name(certificate) == name
        certificate.verify_directly_issued_by(authority)
        names = certificate.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert {str(entry.value) for entry in names} >= {"127.0.0.1", "10.0.0.1", "robot-b.local"}
        assert (directory / f"{name}.key").stat().st_mode & 0o777 == 0o600
        serialization.load_pem_private_key((directory / f"{name}.key").read_bytes(), None)
    assert (directory / "ca.key").stat().st_mode & 0o777 == 0o600
    assert sorted(path.stem for path in directory.glob("*.pem")) == sorted(["ca", *team_names(3)])
    before = (directory / "r0.pem").read_bytes()
    assert one_line_error(ringtrack("certs", str(directory), "--robots", "3")) == (
        f"ringtrack: error: {directory} exists; give another DIR, or --force to replace its certificates")
    assert (directory / "r0.pem").read_bytes() == before
    assert ringtrack("certs", str(directory), "--robots", "4", "--force").returncode == 0
    assert (directory / "r0.pem").read_bytes() != before and (directory / "r3.pem").exists()
    shown = ringtrack("certs", str(directory), "--show")
    assert shown.returncode == 0, shown.stderr
    expires = x509.load_pem_x509_certificate((directory / "r3.pem").read_bytes()).not_valid_after_utc
    assert "a team of 4 robots" in shown.stdout and f"{expires:%Y-%m-%d %H:%M}" in shown.stdout
    assert all(f"{name}.pem" in shown.stdout for name in team_names(4))


def test_the_policy_is_generated_from_the_key_scheme() -> None:
    policy = access_policy(6)
    assert policy["default_permission"] == "deny"
    subjects = {subject["id"]: subject["cert_common_names"] for subject in policy["subjects"]}
    assert subjects == {name: [name] for name in ["world", "monitor", "fusion", *map(robot_name, range(6))]}
    rules = {rule["id"]: rule for rule in policy["rules"]}
    keys = Keys(0x1234)
    # robot 3 may send exactly what its own keys name: a data key whose source is r3
    assert rules["r3-sends"]["key_exprs"] == ["ringtrack/*/*/r3/*"]
    assert keys.data("r4", "r3", "reply").split("/")[2:] == ["r4", "r3", "reply"]
    assert rules["r3-tokens"]["key_exprs"] == ["ringtrack/*/alive/r3", "ringtrack/*/ready/r3", "ringtrack/*/claim/r3/*",
                                               "ringtrack/*/reach/*/r3"]
    assert keys.reach("r2", "r3").split("/")[2:] == ["reach", "r2", "r3"]  # r3 says it sees r2
    assert rules["monitor-subscribes"]["key_exprs"] == ["ringtrack/*/**"]
    assert rules["r3-subscribes"]["key_exprs"] == ["ringtrack/*/r3/**", "ringtrack/*/all/**"]
    assert all(rule["flows"] == ["ingress"] for name, rule in rules.items() if name != "send-to-team")
    assert "router" not in subjects and "router" in {s["id"] for s in access_policy(6, routers=True)["subjects"]}


@pytest.mark.processes
@pytest.mark.timeout(180)
def test_errors_name_the_fix(team: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    shutil.copytree(team, broken)
    # a certificate for another participant than --id
    shutil.copy(broken / "r2.pem", broken / "r3.pem")
    shutil.copy(broken / "r2.key", broken / "r3.key")
    # an expired certificate, signed by the team's own authority
    authority_key = serialization.load_pem_private_key((broken / "ca.key").read_bytes(), None)
    authority = x509.load_pem_x509_certificate((broken / "ca.pem").read_bytes())
    past = datetime.datetime.now(datetime.UTC) - datetime.timedelta(days=30)
    _, expired = issue(authority_key, authority, "r1", valid_from=past, valid_days=2)  # type: ignore[arg-type]
    (broken / "r1.pem").write_bytes(expired.public_bytes(serialization.Encoding.PEM))
    (broken / "r4.pem").unlink()
    robot = ["robot", "--secure", str(broken), "--id"]
    assert one_line_error(ringtrack(*robot, "3")) == (
        f"ringtrack: error: {broken}/r3.pem is the certificate of 'r2', not of 'r3'; copy r3.pem and r3.key from "
        "the team folder of ringtrack certs")
    assert one_line_error(ringtrack(*robot, "1")) == (
        f"ringtrack: error: {broken}/r1.pem expired on {past + datetime.timedelta(days=2):%Y-%m-%d %H:%M} UTC; make "
        f"new certificates: ringtrack certs {broken} --robots 6 --force")
    assert one_line_error(ringtrack(*robot, "4")) == (
        f"ringtrack: error: {broken}/r4.pem is missing; copy it from the team folder made by ringtrack certs")
    assert one_line_error(ringtrack(*robot, "7", "--robots", "8")) == (
        f"ringtrack: error: --secure {broken} was made for a team of 6 robots, not 8; run ringtrack certs {broken} "
        "--robots 8 --force and copy the folder to every host")
    assert one_line_error(ringtrack("spawn", "--secure", str(team), "--robots", "7")).startswith(
        f"ringtrack: error: --secure {team} was made for a team of 6 robots, not 7")
    assert one_line_error(ringtrack(*robot, "0", "--connect", "tcp/127.0.0.1:7447")) == (
        "ringtrack: error: --connect tcp/127.0.0.1:7447: a --secure participant speaks only TLS; write "
        "tls/127.0.0.1:7447")
    assert one_line_error(ringtrack("robot", "--id", "0", "--connect", "tls/127.0.0.1:7447")) == (
        "ringtrack: error: --connect tls/127.0.0.1:7447: TLS needs the team's certificates; add --secure DIR")
    with pytest.raises(SecurityError, match="no team.json"):
        load_team(tmp_path)
    assert isinstance(SecurityError("x"), BusError)  # one-line errors of the command line


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.processes
@pytest.mark.timeout(120)
def test_a_secure_participant_pointed_at_a_plain_one_or_another_team_is_told_so(team: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    create_team(other, 6)
    plain_port, foreign_port = free_port(), free_port()
    worlds = [
        subprocess.Popen([*RINGTRACK, "world", "--listen", f"tcp/127.0.0.1:{plain_port}"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.PIPE),
        subprocess.Popen([*RINGTRACK, "world", "--secure", str(other), "--listen", f"tls/127.0.0.1:{foreign_port}"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.PIPE),
    ]
    try:
        for port in (plain_port, foreign_port):
            wait_for_listener(port)
        robot = ["robot", "--secure", str(team), "--id", "0", "--connect"]
        assert one_line_error(ringtrack(*robot, f"tls/127.0.0.1:{plain_port}")) == (
            f"ringtrack: error: --connect tls/127.0.0.1:{plain_port}: the participant there does not speak TLS "
            f"(TimeoutError): it is a plain one; start it with --secure {team} too")
        assert one_line_error(ringtrack(*robot, f"tls/127.0.0.1:{foreign_port}")).startswith(
            f"ringtrack: error: --connect tls/127.0.0.1:{foreign_port}: the participant there is not of this team (")
    finally:
        for world in worlds:
            world.kill()
            world.wait()


def wait_for_listener(port: int, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise AssertionError(f"nothing listens on port {port}")


# ---------------------------------------------------------------------------------- secure teams
@pytest.mark.processes
@pytest.mark.timeout(300)
def test_a_secure_lockstep_team_of_six_converges_and_equals_the_engine(team: Path, tmp_path: Path) -> None:
    result = spawn_team(TeamPlan(scenario=scenario(), clock="lockstep", runs=tmp_path, dashboard=False, until_converged=True,
                        secure=team))
    assert result.exit_code == 0, result
    assert json.loads((Path(result.folder) / "world-endpoints.json").read_text())["endpoints"][0].startswith("tls/")
    log = read_log(Path(result.log))
    assert log.end["reason"] == "converged" and len(log.steps) == CONVERGED_AT
    assert log.end["consistent"] is True
    assert_equals_engine(log)


INTRUSION_ROUNDS = 200  # rounds of forgeries each intruder sends, 10 ms apart (about 2 s on a quiet machine)


def intrude(tmp_path: Path, team: Path, intruders: list[tuple[str, str]]) -> tuple[list[dict], object]:
    """Run a secure lockstep team that outlasts ``intruders`` ((how, certificate name) for
    tests/intruder.py, all at once); return what each reported and the run log."""
    process = start_spawn(tmp_path, "--secure", str(team), "--steps", "1500")
    try:
        folder = wait_for_steps(tmp_path, 5)
        started = [subprocess.Popen([sys.executable, "-m", "tests.intruder", str(folder), str(INTRUSION_ROUNDS), how, name],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                   for how, name in intruders]
        reports = []
        for intruder in started:
            stdout, stderr = intruder.communicate(timeout=60)
            assert intruder.returncode == 0, stderr
            reports.append(json.loads(stdout))
        assert process.poll() is None, "the run ended before the intruders did: give it more steps"
        assert process.wait(timeout=240) == 0
    finally:
        stop_all(process)
    log = read_log(folder / "log.jsonl")
    return reports, log


def assert_nothing_arrived(log: object, reports: list[dict]) -> None:
    assert len(log.steps) == 1500 and log.end["reason"] == "done"  # no forged End stopped anyone
    assert_equals_engine(log)  # nothing the intruders sent moved any robot
    assert log.end["rejected"] == {} and all(counts == {} for counts in log.end["rejected_by"].values())
    assert log.end["notes"].get("ignored_replies", 0) == 0  # no forged reply reached a robot
    assert log.end["consistent"] is True  # the monitor saw exactly what the team's senders counted
    for report in reports:
        assert report["sent"] == dict.fromkeys(("request", "reply", "command", "end"), INTRUSION_ROUNDS)


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_outsiders_without_tls_or_with_another_authority_get_no_link(team: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    create_team(other, 6)
    reports, log = intrude(tmp_path / "runs", team, [("plain", "r2"), (f"foreign:{other}", "r2")])
    assert_nothing_arrived(log, reports)
    # How the refusal showed: the TLS handshake failed, so neither had a single link to anyone.
    assert [report["links"] for report in reports] == [0, 0]
    print(f"outsiders: plain sent {sum(reports[0]['sent'].values())}, foreign authority sent "
          f"{sum(reports[1]['sent'].values())}: no link (TLS refused), nothing received by anyone")


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_genuine_certificates_cannot_speak_for_another_robot_or_end_the_run(team: Path, tmp_path: Path) -> None:
    holders = ["r2", "monitor", "fusion", "router"]
    reports, log = intrude(tmp_path / "runs", team, [("genuine", name) for name in holders])
    assert_nothing_arrived(log, reports)
    # How the refusal showed: they were linked to the team (mutual TLS accepted their certificates),
    # yet the access control of every receiver dropped all they sent as robot 3 and as the world.
    assert all(report["links"] >= 1 for report in reports), reports
    print(f"insiders {holders}: linked ({[report['links'] for report in reports]} links), sent "
          f"{sum(sum(report['sent'].values()) for report in reports)} forgeries as r3 and world: none delivered")


def test_a_security_config_is_tls_only_and_carries_the_policy_for_peers_not_clients(team: Path) -> None:
    security = Security(check_team(team, ["r0"]), 6)
    peer = security.settings("r0", "peer")
    assert peer["transport/link/tls/enable_mtls"] is True
    assert peer["transport/link/tls/listen_certificate"] == str((team / "r0.pem").resolve())
    assert peer["access_control"] == access_policy(6)
    assert "access_control" not in security.settings("r0", "client")  # the router it links to enforces
    with pytest.raises(BusError, match="speaks only TLS"):
        BusConfig(security=security)  # the plain default listener
    BusConfig(listen=("tls/127.0.0.1:0",), security=security).to_zenoh("r0")


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_the_benchmark_compares_plain_and_secure_runs(tmp_path: Path) -> None:
    path = tmp_path / "bench.json"
    # 300 steps: the stepping must outlast the moment the isolated run's watcher notices the first
    # step, or a loaded machine leaves it no stepping bytes to count (seen with two CPU burners at 40).
    assert main(["bench", "emulator", "--robots", "3", "--steps", "300", "--secure", "compare",
                 "--runs", str(tmp_path / "runs"), "--json", str(path)]) == 0
    (row,) = json.loads(path.read_text())["rows"]
    assert len(row["runs_steps_per_s"]) == len(row["runs_steps_per_s_secure"]) == 1
    assert row["steps_per_s"] > 0 and row["steps_per_s_secure"] > 0
    assert row["security_cost"] == pytest.approx(1 - row["steps_per_s_secure"] / row["steps_per_s"])
    for kind in ("request", "reply", "measurement", "command"):  # TLS works below the payloads
        assert row["bytes_per_message_secure"][kind] == row["bytes_per_message"][kind]
    if isolation_works():
        # every message crosses the namespace's loopback at least once, with its payload
        least = min(row["bytes_per_message"].values())
        assert row["wire_bytes_per_message"]["plain"] > least and row["wire_bytes_per_message"]["secure"] > least
        assert row["startup_wire_bytes"]["secure"] > 0 and row["startup_wire_bytes"]["plain"] > 0
    else:
        assert row["wire_bytes_per_message"] is None
