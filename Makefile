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
test: setup
	@source env/activate && python -m pytest; rc=$$?; [ $$rc -eq 5 ] && rc=0; exit $$rc
