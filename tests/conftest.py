"""Shared pytest set-up: every test run keeps ROS traffic on loopback, in a domain of its own,
with a writable log dir."""
import os
import random
import tempfile

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# label embeddings new to the shipped table go to a per-run cache, not the user's
os.environ["SGREG_CACHE_DIR"] = tempfile.mkdtemp(prefix="sgreg-cache-")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="sgreg-roslog-"))
# One domain per pytest run so parallel runs (CI and a developer) never see each other.
os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 100))
