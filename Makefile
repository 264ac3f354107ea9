# flight_fdi — the two commands a newcomer needs are `make demo` and `make test`;
# both run `make setup` (idempotent) first.
.PHONY: setup demo test bench clean

BAG ?= bags/accel_fault_500s

setup:
	@bash tools/setup.sh

demo: setup
	@.venv/bin/flight-fdi run $(BAG)

test: setup
	@.venv/bin/python -m pytest

bench: setup
	@for b in bench/bench_*.py; do echo "== $$b"; .venv/bin/python $$b || exit 1; done

clean:
	rm -rf build install log
