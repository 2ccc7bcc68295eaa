"""``adaptiveh fleet``: a fleet's arms placed on a Ray cluster, one Ray actor per arm.

Ray does the placing, starting and restarting; Zenoh carries the data; this module only says what runs.
Each arm is one actor (``ArmHost``) in one bundle of a SPREAD placement group (arms go to distinct nodes
as far as the cluster allows, and a restarted arm comes back in its bundle, on its node). The actor
starts the arm's parts as ``adaptiveh up`` would (``Stack.part_commands`` and ``part_environment``: the
same command lines, the operator token in the environment, logs 0600) and dies when one of them exits,
so Ray restarts the arm whole (``max_restarts``, default ``supervisor.max_restarts``). An arm that used
its restarts is reported and the others keep going; ``stop`` (Ctrl-C, SIGTERM) stops every arm's parts,
actor first, and a driver killed outright takes its actors with it (Ray's ownership), their parts with
them (``die_with_supervisor``).

The learner and monitor are not placed: they stay with the operator, where ``adaptiveh up CONFIG --arms
none`` runs them (the learner outlives arms that come and go, and its checkpoint, recording and page stay
on the operator's machine). The arms reach it as clients of Zenoh routers (``adaptiveh router``, as in
docs/howto/parts.md): the config's ``zenoh.connect``, or ``--connect``.

This tree is shipped to the nodes as the Ray job's ``working_dir`` (every arm runs the learner's code);
the nodes need the Python environment (the project installed, its drivers) and, on a secured bus, their
certificates at the config's paths. The arm's config, as its parts read it, and their logs are written
on its node under ``<node_dir>/<name>/<arm>/``; the token travels as the actor's argument, never argv.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ray
import yaml
from ray.exceptions import RayActorError
from ray.util.placement_group import PlacementGroup, placement_group, remove_placement_group
from ray.util.scheduling_strategies import PlacementGroupSchedulingStrategy

from common.config import parse
from common.errors import AdaptiveHError
from deploy.config import StackConfig, compose_stack_yaml
from deploy.stack import Stack

log = logging.getLogger(__name__)

CODE_ROOT = Path(__file__).resolve().parents[1]
# Not shipped to the nodes (nor .git, .venv and what .gitignore names, which Ray leaves out itself).
SHIP_EXCLUDES = ["results", "runs", "shared", "tests", "*.egg-info", "__pycache__"]
NAMESPACE = "adaptiveh"  # the arms' actors are named <fleet>/<arm> in it: one placement per arm
PLACE_TIMEOUT_S = 120.0  # for the cluster to reserve the arms' bundles, then for each arm to start
STOP_TIMEOUT_S = 40.0  # for the arms to stop their parts (each part has 15 s before SIGKILL)
POLL_S = 2.0


class FleetError(AdaptiveHError):
    """The fleet cannot be placed: the config, the Ray address or the cluster's resources."""


def fleet_config(
    path: str | Path, arms: int, connect: tuple[str, ...] = ()
) -> tuple[dict[str, Any], StackConfig]:
    """The config at ``path`` as the placed arms read it: its fleet cut or grown to ``arms`` arms (beyond
    the named ones ``arm<i>`` with seed ``i``, ``i`` counting from 0 over the fleet), its arms clients of
    the routers at ``connect`` (default: ``zenoh.connect``). Checked before anything is placed: the
    mapping shipped to the nodes, and its model."""
    data = compose_stack_yaml(path)
    fleet = parse(StackConfig, data, str(path)).fleet
    if fleet is None:
        raise FleetError(
            f"{path}: no fleet section; adaptiveh fleet places a fleet's arms (configs/fleet.yaml)"
        )
    if arms < 1:
        raise FleetError(f"--arms {arms}: place at least one arm")
    named = [a.model_dump() for a in fleet.arms[:arms]]
    grown = [{"name": f"arm{i}", "seed": i} for i in range(len(named), arms)]
    data["fleet"] = {**data["fleet"], "arms": named + grown}
    zenoh = {**(data.get("zenoh") or {}), "mode": "client"}  # tried: as peers, the test's arm never played
    data["zenoh"] = {**zenoh, "connect": list(connect)} if connect else zenoh
    cfg = parse(StackConfig, data, str(path))
    if not cfg.zenoh.connect:
        raise FleetError(
            f"{path}: zenoh.connect is empty, so each arm would look for the bus on its own node; name the"
            " learner's routers with --connect tcp/LEARNER_HOST:7447 (there: adaptiveh router) or in zenoh"
        )
    data["name"] = cfg.name  # its default made explicit: the arms' folders on the nodes are named by it
    return data, cfg


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """A FleetError at once, instead of Ray's long retries, when nothing answers at ``address``
    (``host:port`` or ``ray://host:port``; ``auto`` is Ray's own to find)."""
    if address == "auto":
        return
    host, _, port = address.split("://")[-1].rpartition(":")
    if not host or not port.isdigit():
        raise FleetError(
            f"--ray {address}: expected HOST:PORT, e.g. 10.0.0.5:6379 (ray start --head prints it)"
        )
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise FleetError(f"no Ray cluster at {address} ({exc}): is ray start --head running there?") from None


@dataclass(frozen=True)
class Placed:
    """Where an arm runs: its node, its actor's process, its parts' pids and its folder there."""

    arm: str
    node_id: str
    ip: str
    host: str
    pid: int
    parts: dict[str, int]
    dir: str


class ArmHost:
    """One arm's parts on the node Ray placed it on (a Ray actor): started at once, stopped by ``stop``;
    a part that exits ends this process, for Ray to restart the arm."""

    def __init__(self, arm: str, config: dict[str, Any], token: str, node_dir: str) -> None:
        self.arm = arm
        self.dir = Path(node_dir).expanduser() / config["name"] / arm
        self.dir.mkdir(mode=0o700, parents=True, exist_ok=True)
        path = self.dir / "config.yaml"
        path.write_text(yaml.safe_dump(config))
        self.stack = Stack(path, run_dir=self.dir, token=token, progress=False, arms=[arm])
        self._lock = threading.Lock()
        self._stopping = False
        parts = self.stack.part_commands()
        if _restarted():  # Ray brought this arm back: its parts' logs go on
            self.stack.restarts = dict.fromkeys(parts, 1)
        for part in parts:
            self.stack.spawn(part)
        threading.Thread(target=self._watch, name=f"watch-{arm}", daemon=True).start()

    def _watch(self) -> None:
        while True:
            time.sleep(0.5)
            with self._lock:
                if self._stopping:
                    return
                gone = {p: proc.returncode for p, proc in self.stack.procs.items() if proc.poll() is not None}
                if gone:
                    why = f"{', '.join(gone)} exited (logs: {self.dir / 'logs'})"
                    log.error("arm %s: %s; Ray restarts the arm if it has restarts left", self.arm, why)
                    self.stack.stop_parts()
                    os._exit(1)  # an actor's process that dies is what Ray restarts

    @ray.method(max_task_retries=-1)  # answered once the arm is back, if Ray restarts it meanwhile
    def where(self) -> Placed:
        ctx = ray.get_runtime_context()
        parts = {p: proc.pid for p, proc in self.stack.procs.items()}
        ip = ray.util.get_node_ip_address()
        return Placed(
            self.arm, ctx.get_node_id(), ip, socket.gethostname(), os.getpid(), parts, str(self.dir)
        )

    def stop(self) -> dict[str, int | None]:
        """Stop the parts (the actor before robot-io, as the supervisor does); their exit codes."""
        with self._lock:
            self._stopping = True
            self.stack.stop_parts()
        return {p: proc.returncode for p, proc in self.stack.procs.items()}


def _restarted() -> bool:
    """Whether Ray restarted this actor (Ray's own property warns of an API that it calls itself)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return bool(ray.get_runtime_context().was_current_actor_reconstructed)


@dataclass
class Placement:
    """How each arm is placed: the Ray resources its bundle holds and how often Ray restarts it."""

    cpus: float
    resource: str  # a custom resource each arm takes one unit of ("": none)
    max_restarts: int
    node_dir: str  # on each node (``~`` is the node's): <node_dir>/<name>/<arm>/

    def __post_init__(self) -> None:
        if self.cpus <= 0 or self.max_restarts < 0:
            raise FleetError(
                f"--cpus-per-arm {self.cpus:g} must be > 0, --max-restarts {self.max_restarts} >= 0"
            )

    def bundle(self) -> dict[str, float]:
        return {"CPU": self.cpus, **({self.resource: 1.0} if self.resource else {})}


class RayFleet:
    """The driver: connect to the cluster, place the arms, watch them, stop them."""

    def __init__(self, config: dict[str, Any], token: str, placement: Placement) -> None:
        self.config = config
        self.name = config["name"]
        self.arms = [a["name"] for a in config["fleet"]["arms"]]
        self.token = token
        self.placement = placement
        self.pg: PlacementGroup | None = None
        self.actors: dict[str, Any] = {}  # arm -> its ArmHost actor
        self.placed: dict[str, Placed] = {}
        self.restarts: dict[str, int] = dict.fromkeys(self.arms, 0)
        self.gave_up: list[str] = []
        self._stop = threading.Event()

    def request_stop(self) -> None:
        self._stop.set()

    def connect(self, address: str) -> None:
        check_reachable(address)
        env = {"working_dir": str(CODE_ROOT), "excludes": SHIP_EXCLUDES}
        try:
            ray.init(address=address, namespace=NAMESPACE, runtime_env=env, logging_level="WARNING")
        except (ConnectionError, RuntimeError) as exc:
            raise FleetError(f"cannot join the Ray cluster at {address}: {exc}") from None

    def place(self) -> dict[str, Placed]:
        """Reserve a bundle per arm (SPREAD), start each arm's actor in its own; where each runs."""
        bundle = self.placement.bundle()
        self._check_capacity(bundle)
        self.pg = placement_group([bundle] * len(self.arms), strategy="SPREAD", name=f"adaptiveh-{self.name}")
        if not self._wait([self.pg.ready()], f"{len(self.arms)} bundles of {bundle}"):
            return {}
        host = ray.remote(ArmHost)
        for i, arm in enumerate(self.arms):
            self.actors[arm] = self._start(host, i, arm)
        refs = {arm: actor.where.remote() for arm, actor in self.actors.items()}
        if not self._wait(list(refs.values()), "the arms to start"):
            return {}
        for arm, ref in refs.items():
            try:
                self.placed[arm] = ray.get(ref, timeout=0)
            except RayActorError as exc:
                raise FleetError(f"arm {arm} did not start on its node: {exc}") from None
        return dict(self.placed)

    def _check_capacity(self, bundle: dict[str, float]) -> None:
        """A FleetError at once when the whole cluster has less of a resource than the arms need."""
        total, n = ray.cluster_resources(), len(self.arms)
        for key, each in bundle.items():
            if total.get(key, 0.0) < each * n:
                have = total.get(key, 0.0)
                raise FleetError(
                    f"{n} arms need {each * n:g} {key} and the cluster's nodes have {have:g} in all"
                )

    def _start(self, host: Any, index: int, arm: str) -> Any:
        opts = self.placement
        try:
            return host.options(
                name=f"{self.name}/{arm}",
                num_cpus=opts.cpus,
                resources={opts.resource: 1.0} if opts.resource else {},
                max_restarts=opts.max_restarts,
                scheduling_strategy=PlacementGroupSchedulingStrategy(self.pg, index),
            ).remote(arm, self.config, self.token, opts.node_dir)
        except ValueError as exc:  # the name is taken: another driver placed this arm
            raise FleetError(
                f"arm {arm} of {self.name} is placed already (another adaptiveh fleet?): {exc}"
            ) from None

    def _wait(self, refs: list[Any], what: str) -> bool:
        """Wait for ``refs`` (False: a stop came first); a FleetError after ``PLACE_TIMEOUT_S``."""
        deadline = time.monotonic() + PLACE_TIMEOUT_S
        while not self._stop.is_set():
            ready, _ = ray.wait(refs, num_returns=len(refs), timeout=1.0)
            if len(ready) == len(refs):
                return True
            if time.monotonic() > deadline:
                free = ray.available_resources()
                raise FleetError(f"Ray did not place {what} in {PLACE_TIMEOUT_S:.0f} s (free now: {free})")
        return False

    def watch(self, duration: float = 0.0) -> list[str]:
        """Until a stop, ``duration`` s (0: no limit) or every arm used its restarts; the arms that did."""
        end = time.monotonic() + duration if duration > 0 else float("inf")
        asked = {arm: actor.where.remote() for arm, actor in self.actors.items()}
        while asked and not self._stop.wait(POLL_S) and time.monotonic() < end:
            ready, _ = ray.wait(list(asked.values()), num_returns=len(asked), timeout=0)
            for arm in [a for a, ref in asked.items() if ref in ready]:
                if self._seen(arm, asked.pop(arm)):
                    asked[arm] = self.actors[arm].where.remote()
        return list(self.gave_up)

    def _seen(self, arm: str, ref: Any) -> bool:
        """Take an arm's answer: True while it lives (a new pid: Ray restarted it), False once it is gone."""
        try:
            now = ray.get(ref, timeout=0)
        except RayActorError as exc:
            last = self.placed[arm]
            logs = f"{last.dir}/logs on {last.host} ({last.ip})"
            log.error(
                "arm %s used its %d restarts and is gone; its logs: %s",
                arm,
                self.placement.max_restarts,
                logs,
            )
            log.debug("arm %s: %s", arm, exc)
            self.gave_up.append(arm)
            return False
        if now.pid != self.placed[arm].pid:
            self.restarts[arm] += 1
            log.warning("arm %s restarted by Ray (restart %d) on node %s", arm, self.restarts[arm], now.ip)
        self.placed[arm] = now
        return True

    def stop(self) -> dict[str, dict[str, int | None] | None]:
        """Stop every arm's parts, end the actors, free the bundles, leave the cluster; exit codes by arm
        (None: the arm was gone or did not answer in time, its parts end with its process)."""
        if not ray.is_initialized():
            return {}
        live = {arm: a.stop.remote() for arm, a in self.actors.items() if arm not in self.gave_up}
        ready, _ = (
            ray.wait(list(live.values()), num_returns=len(live), timeout=STOP_TIMEOUT_S) if live else ([], [])
        )
        codes: dict[str, dict[str, int | None] | None] = dict.fromkeys(self.actors)
        for arm, ref in live.items():
            if ref in ready:
                try:
                    codes[arm] = ray.get(ref, timeout=0)
                except RayActorError:
                    pass
        for actor in self.actors.values():
            ray.kill(actor, no_restart=True)
        if self.pg is not None:
            remove_placement_group(self.pg)
        ray.shutdown()
        return codes
