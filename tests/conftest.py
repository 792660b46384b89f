"""Shared pytest set-up: every test run keeps ROS traffic on loopback, in a domain of its own,
with a writable log dir."""
import os
import random
import tempfile

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# label embeddings new to the shipped table go to a per-run cache, not the user's
os.environ["SGREG_CACHE_DIR"] = tempfile.mkdtemp(prefix="sgreg-cache-")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="sgreg-roslog-"))
# One domain per pytest run so parallel runs (CI and a developer) never see each other, and
# under pytest-xdist one per worker: the workers share the run's id and offset it by their index.
_run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
_worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
_base = int(_run, 16) if _run else random.SystemRandom().randrange(100)
os.environ["ROS_DOMAIN_ID"] = str(1 + (_base + int(_worker.removeprefix("gw") or 0)) % 100)
