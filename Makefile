# Convenience targets; the scripts in ci/ work without make.
.PHONY: demo test bench setup
setup:
	bash ci/setup.sh
demo:
	bash ci/demo.sh
test:
	bash ci/test.sh
bench: setup
	.venv/bin/tsplus bench-raster --json bench-out/raster.json
