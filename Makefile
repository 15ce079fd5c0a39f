# Quadrivio: the two commands that do everything from nothing are `make demo` and
# `make test`. Both run `make setup` first (idempotent: seconds when already done).
SHELL := /bin/bash
.DEFAULT_GOAL := help
ENV := source $(CURDIR)/env.sh
RESULTS ?= results

.PHONY: help setup demo test unit system rostest bench soak lint clean

help:
	@echo "make setup   system packages, Python venv, catkin workspace (idempotent)"
	@echo "make demo    setup, then the figure-eight experiment in simulation (headless)"
	@echo "make test    setup, then every unit test, system test and rostest (what CI runs)"
	@echo "make unit    the pytest unit tests only (no ROS master); make system: the pytest system tests"
	@echo "make bench   setup, then the benchmarks (JSON in bench/results/)"
	@echo "make soak    setup, then the long fault-injection cases (bench/results/soak.json)"
	@echo "make lint    catkin_lint and pyflakes"

setup:
	@tools/setup.sh

demo: setup
	@$(ENV) && rosrun quadrivio experiment figure_eight --out $(RESULTS)/demo

test: setup
	@$(ENV) && tools/run_tests.sh

unit: setup
	@$(ENV) && tools/run_tests.sh unit

system: setup
	@$(ENV) && tools/run_tests.sh system

rostest: setup
	@$(ENV) && tools/run_tests.sh rostest

bench: setup
	@$(ENV) && tools/run_bench.sh

soak: setup
	@$(ENV) && tools/run_soak.sh

lint: setup
	@$(ENV) && catkin_lint -W2 .ws/src && python3 -m pyflakes $$(git ls-files '*.py') $$(git ls-files '*/nodes/*' 'nodes/*')

clean:
	rm -rf .ws .setup bench/results $(RESULTS)
