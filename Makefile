# geomodel_ros — the two commands of the README are `make demo` and `make test`.
# Every process started from here keeps DDS discovery on loopback.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export PYTHONDONTWRITEBYTECODE := 1

VENV := .venv
PY := $(VENV)/bin/python

.PHONY: setup demo test bench clean

setup:
	@bash .ci/setup_env.sh

demo: setup
	$(PY) -m geomodel_ros.tools.demo --out demo_out

test: setup
	$(PY) -m pytest -q test

bench: setup
	@mkdir -p bench_out
	$(PY) -m geomodel_ros.cli bench --json bench_out/bench.json
	$(PY) -m geomodel_ros.tools.bench_node

clean:
	rm -rf $(VENV) build install log build_msgs demo_out bench_out
