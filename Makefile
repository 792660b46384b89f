# The two commands a newcomer needs (see README.md):
#   make demo   set up everything (./setup.sh) and replay the first shipped two-agent bag
#   make test   run the test suite
SHELL := /bin/bash
VENV := .venv
DEMO_BAG := bags/apartment_opposite

.PHONY: setup demo test
setup:
	./setup.sh

demo: setup
	@source env/activate && mkdir -p results && \
	sgreg replay $(DEMO_BAG) --json results/demo.json --png results/demo.png

# pytest exits 5 when it collects no test: that is not a failure of the suite.
# Two workers (pytest-xdist), each test file on one: the real-time replays through DDS mostly
# wait, so a second worker takes the suite from about 16 to 10 minutes; each worker has a ROS
# domain of its own (tests/conftest.py). A plain `python -m pytest` runs in one process.
test: setup
	@source env/activate && python -m pytest -n 2 --dist loadfile; rc=$$?; [ $$rc -eq 5 ] && rc=0; exit $$rc
