"""docs/service.md and config/cdro-hostd.example.yaml keep up with the code: every counter and
every configuration key is documented, and the example shows every key."""
from __future__ import annotations

import re

import yaml

SECTIONS = ("serial", "nodes", "schedule", "capture", "output", "jsonl", "mqtt", "mqtt_auth", "http", "checkpoint",
            "odometry", "logging", "web")
# A section of its own whose values live in another section's struct (JsonlLimits in OutputConfig):
# the member is the section, not a key.
NESTED = {"JsonlLimits", "MqttAuthConfig"}


def config_keys(repo_root):
    header = (repo_root / "host/service/include/cdro/service/config.hpp").read_text()
    keys = {}
    for section, struct in [("serial", "SerialConfig"), ("nodes", "NodesConfig"), ("schedule", "ScheduleConfig"),
                            ("capture", "CaptureConfig"), ("output", "OutputConfig"), ("jsonl", "JsonlLimits"),
                            ("mqtt", "MqttConfig"), ("mqtt_auth", "MqttAuthConfig"),
                            ("http", "HttpConfig"), ("checkpoint", "CheckpointConfig"),
                            ("odometry", "OdometryConfig"), ("logging", "LoggingConfig"),
                            ("web.floor_plan", "FloorPlanConfig")]:
        body = re.search(rf"struct {struct} \{{(.*?)\n\}};", header, re.S).group(1)
        keys[section] = [name for kind, name in re.findall(r"^\s+([\w:<>]+) (\w+)(?: = [^;]*)?;", body, re.M)
                         if kind not in NESTED]
    return keys


def test_every_counter_is_documented(repo_root):
    header = (repo_root / "host/service/include/cdro/service/counters.hpp").read_text()
    counters = re.findall(r"^\s+X\((\w+), \"", header, re.M)
    assert len(counters) > 40
    doc = (repo_root / "docs/service.md").read_text()
    missing = [name for name in counters if f"| `{name}` |" not in doc]
    assert not missing, f"counters missing from docs/service.md: {missing}"


def test_every_config_key_is_documented_and_in_the_example(repo_root):
    doc = (repo_root / "docs/service.md").read_text()
    example = yaml.safe_load((repo_root / "config/cdro-hostd.example.yaml").read_text())
    for section, keys in config_keys(repo_root).items():
        assert keys, section
        for key in keys:
            assert f"| `{section}.{key}` |" in doc, f"{section}.{key} missing from docs/service.md"
            in_example = example
            for part in section.split("."):
                in_example = in_example[part]
            assert key in in_example, f"{section}.{key} missing from the example config"
