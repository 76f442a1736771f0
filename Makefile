# Two commands do all set-up on a fresh Debian machine with Python 3.11:
#   make demo   - the main job (environment, server, simulated robot)
#   make test   - the environment and the whole test suite
PYTHON ?= python3.11
VENV := .venv
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test lint serve screenshot clean

$(STAMP): pyproject.toml scripts/setup-system.sh
	./scripts/setup-system.sh
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	# OpenCV with contrib replaced opencv-python-headless: both write cv2/, never keep both
	$(VENV)/bin/pip uninstall -y -q opencv-python-headless 2>/dev/null || true
	# every extra (server, simulator, ROS 2 and Pi drivers) and the test tools; a robot installs
	# the client alone: pip install '.[ros2]' or '.[pi]' (docs/robot.md, "Install on the robot")
	$(VENV)/bin/pip install -q -e '.[server,sim,ros2,pi,dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/teachrepeat demo

test: $(STAMP)
	$(VENV)/bin/pytest -q -n auto --dist worksteal

lint: $(STAMP)
	$(VENV)/bin/ruff check . && $(VENV)/bin/ruff format --check . && $(VENV)/bin/mypy

serve: $(STAMP)
	$(VENV)/bin/teachrepeat serve

screenshot: $(STAMP)
	DASHBOARD_SCREENSHOT=docs/img/dashboard.png TIMELINE_SCREENSHOT=docs/img/timeline.png \
		AGENT_SCREENSHOTS=docs/img $(VENV)/bin/pytest -q tests/e2e/test_e2e_dashboard.py \
		tests/e2e/test_e2e_timeline.py tests/e2e/test_e2e_teach_by_driving.py

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
