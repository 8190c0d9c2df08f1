"""Shared fixtures: small real collections (real PyBullet, real MuJoCo, real lerobot)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from acn.toolkit.collector import CollectConfig, collect_episodes  # noqa: E402


@pytest.fixture(scope="session")
def small_config() -> CollectConfig:
    return CollectConfig(source="pybullet", target="mujoco", policy="trot", episodes=2, seconds=1.0, seed=3)


@pytest.fixture(scope="session")
def small_episodes(small_config):
    return collect_episodes(small_config, list(range(small_config.episodes)))


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory, small_config):
    from acn.datasets.record import record

    return record(small_config, tmp_path_factory.mktemp("data") / "paired")


def load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(f"acn/{root.name}", root=root)
