"""What both nodes share: parameters declared from the configs (the live ones applied at run
time), the agent id and its topics, the model, and one health status on /diagnostics."""
from __future__ import annotations

import os
import time
from dataclasses import replace

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

from sgreg_core.net.model import SGRegModel, load_model
from sgreg_core.runtime.agent import NotYet
from sgreg_core.runtime.auth import AuthConfig
from sgreg_core.runtime.clock import RunClock
from sgreg_core.runtime.health import Health, HealthConfig

from . import convert, qos
from .params import (Param, accept_live_changes, agent_name_from, declare_and_read, node_parameter_names,
                     overrides_of, pick, unknown_parameters)
from .signing import MessageAuth


LOG_PERIOD_S = 10.0


class SgregNode(Node):
    """Subclasses declare their parameter table, build their core, then call `ready()`; they
    apply live parameters in `apply` and describe themselves in `summary`."""

    def __init__(self, executable: str, table: list[Param], sole_topic: str):
        """sole_topic: /<agent>/<sole_topic> is published by this node of the agent alone; a
        second publisher means a second agent of this name (diagnostics say ERROR)."""
        super().__init__(executable)   # the node is called what it is run as
        self.table = table
        self.in_effect(overrides_of(self))
        self.p = declare_and_read(self, table)
        for line in unknown_parameters(overrides_of(self), node_parameter_names()):
            self.get_logger().warning(line)
        self.name = agent_name_from(self, self.p["agent_name"])
        self.run_clock = RunClock()
        self.health = Health(HealthConfig(**pick(HealthConfig, self.p)), self.clock_s())
        self.auth = MessageAuth(AuthConfig(**pick(AuthConfig, self.p)), self.name, self.get_logger())
        if self.auth.keystore is not None:    # (without one, MessageAuth says so, loudly)
            fleet = ", ".join(sorted(set(self.auth.keystore.owners.values())))
            self.get_logger().info(f"signing as '{self.name}' (key {self.auth.key_id}); fleet "
                                   f"keystore {self.auth.keystore.root}: agents {fleet}")
        self.problem: str | None = None      # why the node cannot do its job at all
        self.sole_topic = self.topic(sole_topic)
        self.twin: str | None = None         # another node publishing sole_topic
        self.last_map_at: float | None = None
        self._logged: dict[str, tuple[float, int]] = {}   # refusal kind -> (last logged, suppressed)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", qos.DIAGNOSTICS)
        self.create_timer(1.0, self.publish_diagnostics)

    def in_effect(self, overrides: dict) -> None:
        """Change what a params file or -p gave (name -> rclpy Parameter) into what the node
        will use, before the parameters are declared: `ros2 param get` then reads the value in
        effect."""

    def topic(self, suffix: str) -> str:
        """/<agent>/<suffix>: the agent id, not the namespace, names the topics (they agree,
        or agent_name was given without a namespace)."""
        return f"/{self.name}/{suffix}"

    def load_model(self) -> SGRegModel | None:
        """The model, or None with `problem` set: the node then only reports ERROR."""
        try:
            return load_model(self.p["weights_path"] or None)
        except Exception as exc:  # missing file, bad JSON, wrong shapes: all mean "no model"
            self.problem = f"no model: {exc}"
            self.get_logger().error(f"{self.problem}; this node will only report diagnostics")
            return None

    def accept_live_parameters(self) -> None:
        accept_live_changes(self, self.table, self._apply)

    def _apply(self, changes: dict) -> None:
        # every new config is built (and refused, ValueError) before anything changes: a
        # refused set leaves the node, and what `ros2 param get` says, as they were
        health = pick(HealthConfig, changes)
        health_cfg = replace(self.health.cfg, **health) if health else self.health.cfg
        self.apply(changes)
        self.health.cfg = health_cfg
        self.p.update(changes)
        self.get_logger().info("parameters set: " + ", ".join(f"{k}={v!r}" for k, v in changes.items()))

    def apply(self, changes: dict) -> None:
        """Apply live parameters (each already in range) to the node's core: build every new
        config first (ValueError when they do not fit together), then assign them."""

    def guarded(self, what: str, work, refuse) -> None:
        """work(), and a bug in it costs that one piece of work, not the node: logged and
        counted as internal_error by refuse(counter, why) -> the line to log."""
        try:
            work()
        except Exception as exc:
            self.get_logger().error(refuse("internal_error", f"{what}: internal error {exc!r}; skipped"))

    def map_taken(self, why: str | None) -> None:
        """After the own instance map was offered: log why it was refused, or note its time (a
        map too small to use yet, NotYet, is the front end at work: noted, and said at info)."""
        if isinstance(why, NotYet):
            self.last_map_at = self.clock_s()
            self.refusal(why, key="small map", quiet=True)
        elif why:
            self.refusal(why)
        else:
            self.last_map_at = self.clock_s()

    def refusal(self, why: str, key: str | None = None, quiet: bool = False) -> None:
        """Log a refused input (a warning; quiet: at info, for an input only waited out), at
        most once per LOG_PERIOD_S per kind (the first words, or `key`): a flood of bad
        messages costs counters, not a flood of log lines."""
        key = key or " ".join(why.split()[:3])
        now = time.monotonic()
        last, suppressed = self._logged.get(key, (-1e9, 0))
        if now - last < LOG_PERIOD_S:
            self._logged[key] = (last, suppressed + 1)
            return
        if len(self._logged) > 1000:
            self._logged.clear()
        self._logged[key] = (now, 0)
        more = f" ({suppressed} more like it in the last {LOG_PERIOD_S:g} s)" if suppressed else ""
        # rclpy fixes one severity per call site: one line each
        if quiet:
            self.get_logger().info(why + more)
        else:
            self.get_logger().warning(why + more)

    # ---- diagnostics ---------------------------------------------------------------------
    def counters(self) -> dict:
        return {}

    def refused(self) -> int:
        return 0

    def summary(self) -> str:
        return ""

    def check_twin(self) -> None:
        """Another node publishing this node's sole topic: two agents run under one name, and
        their peers take their maps for one agent's that restarts (ERROR while it lasts)."""
        mine = sum(pub.topic_name == self.sole_topic for pub in self.publishers)   # none without a model
        others = self.count_publishers(self.sole_topic) - mine
        # the pid tells the twins' lines apart (both nodes have one name) and which one to stop
        twin = (f"{others} other node(s) publish {self.sole_topic}: is agent '{self.name}' "
                f"running twice? (this one is process {os.getpid()})") if others > 0 else None
        if twin and twin != self.twin:
            self.get_logger().error(twin)
        self.twin = twin

    def publish_diagnostics(self) -> None:
        self.check_twin()
        level, message = self.health.status(self.clock_s(), self.refused(), self.last_map_at,
                                            self.problem or self.twin)
        self.diag_pub.publish(convert.diagnostics_msg(
            self.get_fully_qualified_name(), self.name, level, message or self.summary(),
            self.counters(), self.now_ns()))

    def now_ns(self) -> int:
        """ROS time (the bag's /clock under use_sim_time): what outputs are stamped with."""
        return self.get_clock().now().nanoseconds

    def stamp_clock_ns(self) -> int:
        """The clock a map's stamp is checked against (convert.take_instance_map): ROS time,
        and 0 (no check) under use_sim_time, where a bag's clock need not be its maps'."""
        clock = self.get_clock()
        return 0 if clock.ros_time_is_active else clock.now().nanoseconds

    def clock_s(self) -> float:
        """What the core's intervals and timeouts run on (runtime/clock.py): the bag's clock
        under use_sim_time, so that a paused or faster bag keeps the link's timing; never
        going back."""
        clock = self.get_clock()
        return self.run_clock.read(clock.ros_time_is_active, clock.now().nanoseconds, time.monotonic())
