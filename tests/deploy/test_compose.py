"""deploy/container/compose.yml: N machines from one image, each with its own
config, state volume, secret and health check. Parsed here (Docker Compose
itself is not installed on this machine: `docker compose config` is not run)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
COMPOSE = REPO / "deploy" / "container" / "compose.yml"
CONTAINERFILE = REPO / "deploy" / "container" / "Containerfile"


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    data = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    assert isinstance(data, dict)
    return data


def test_several_machines_from_one_image(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert len(services) >= 2
    # the YAML merge key gave every service the shared settings
    assert {s["image"] for s in services.values()} == {"compd:0.1.0"}
    for name, s in services.items():
        assert s["read_only"] is True and s["cap_drop"] == ["ALL"], name
        assert s["security_opt"] == ["no-new-privileges"], name
        assert s["restart"] == "on-failure" and s["stop_grace_period"] == "30s", name


def test_each_machine_has_its_own_config_state_and_secret(compose: dict[str, Any]) -> None:
    services = compose["services"]
    configs, states, secrets = set(), set(), set()
    for name, s in services.items():
        mounts = {v.split(":")[1]: v.split(":")[0] for v in s["volumes"]}
        # the image's CMD runs /etc/compd/compd.toml; the state is the image's VOLUME
        assert mounts.keys() == {"/etc/compd/compd.toml", "/var/lib/compd"}, name
        assert mounts["/etc/compd/compd.toml"] == f"/etc/compd/{name}.toml"
        assert next(v for v in s["volumes"] if v.startswith("/etc/")).endswith(":ro")
        configs.add(mounts["/etc/compd/compd.toml"])
        states.add(mounts["/var/lib/compd"])
        (secret,) = s["secrets"]
        assert secret["target"] == "controller-password"
        secrets.add(secret["source"])
    n = len(services)
    assert len(configs) == len(states) == len(secrets) == n
    assert states == set(compose["volumes"])
    assert secrets == set(compose["secrets"])
    assert all(f"/{name}/" in compose["secrets"][f"{name}-controller-password"]["file"]
               for name in services)


def test_health_checks_run_compd_health_on_distinct_ports(compose: dict[str, Any]) -> None:
    ports = set()
    for name, s in compose["services"].items():
        test = s["healthcheck"]["test"]
        assert test[:3] == ["CMD", "compd", "health"], name
        url = test[test.index("--url") + 1]
        match = re.fullmatch(r"http://127\.0\.0\.1:(\d+)/metrics", url)
        assert match, url
        ports.add(int(match.group(1)))
        assert s["healthcheck"]["start_period"] and s["healthcheck"]["interval"]
    assert len(ports) == len(compose["services"])  # one metrics port per machine


def test_the_image_is_what_the_containerfile_builds() -> None:
    text = CONTAINERFILE.read_text()
    assert 'VOLUME ["/var/lib/compd"]' in text
    assert 'CMD ["run", "/etc/compd/compd.toml"]' in text
