"""The record of how a result was made (mazelab.experiments.journal), as a reader of a paper needs it:
the working folder, every dependency's version, shipped mazes named without the machine's folders, a
generated maze's hash per run (that of `maze generate --seed`'s grid), and the seeds' dtype said."""

from __future__ import annotations

import csv
import hashlib
import json
import os

import numpy as np

from mazelab.cli.app import main
from mazelab.experiments.journal import DEPENDENCIES
from mazelab.maze import Maze
from mazelab.maze_generator import generate_maze


def test_the_record_names_the_folder_the_packages_and_the_shipped_maze_as_the_projects(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = ["study", "--maze", "paper_5x5", "--runs", "1", "--steps", "3", "--particles", "20", "--no-viz"]
    assert main([*args, "--workers", "1", "--csv", "s.csv"]) == 0
    record = json.loads((tmp_path / "s.record.json").read_text())
    assert record["working_folder"] == os.getcwd()
    packages = record["program"]["packages"]
    assert set(packages) == set(DEPENDENCIES) and packages["numpy"] == np.__version__ and packages["pydantic"]
    (maze,) = record["parameters"]["mazes"]
    assert maze["file"] == "mazes/paper_5x5.txt" and maze["shipped"] is True
    assert "maze_seed" in record["csv_dtypes"]


def test_a_generated_mazes_rows_carry_the_sha256_of_its_grid(tmp_path):
    table = tmp_path / "s.csv"
    args = ["study", "--maze-size", "6x6", "--stations", "2", "--runs", "2", "--steps", "3", "--particles", "20"]
    assert main([*args, "--seed", "4", "--no-viz", "--workers", "1", "--csv", str(table)]) == 0
    rows = list(csv.DictReader(table.open()))
    hashes = {r["run"]: r["maze_sha256"] for r in rows}
    assert len(set(hashes.values())) == 2  # a maze of its own per run
    for row in rows:
        world = generate_maze(6, 6, 2, np.random.default_rng(int(row["maze_seed"])))
        assert row["maze_sha256"] == hashlib.sha256(world.to_text().encode()).hexdigest()
    assert isinstance(Maze(world.grid), Maze)
