# flight_fdi — the two commands a newcomer needs are `make demo` and `make test`;
# both run `make setup` (idempotent) first.
.PHONY: setup demo test bench clean

BAG ?= bags/accel_fault_500s
BAG3D ?= bags/ins3d_gyro_x_step

setup:
	@bash tools/setup.sh

demo: setup
	@.venv/bin/flight-fdi run $(BAG)
	@echo
	@echo "== the 3-D model (--model ins3d) on $(BAG3D): gyro x step of 1 deg/h at 480 s, turns after it"
	@.venv/bin/flight-fdi analyze $(BAG3D) --model ins3d

test: setup
	@.venv/bin/python -m pytest

bench: setup
	@for b in bench/bench_*.py; do echo "== $$b"; .venv/bin/python $$b || exit 1; done

clean:
	rm -rf build install log
