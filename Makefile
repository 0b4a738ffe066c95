# heurtune: `make run` sets up and runs the main job, `make test` sets up and runs the tests.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
THESIS_CS_FOLQI_MIN := Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,Ki2=7.1716,alpha1=0.9814,alpha2=0.8437

.PHONY: setup run test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

# Main job (until the experiment runner lands): the thesis CS/FOLQI gains, minimum phase,
# under the nominal and +-30 % plants; trajectories and figure in results/.
run: $(STAMP)
	$(BIN)/python -m heurtune.evaluate cs_folqi_qtp --case min --x "$(THESIS_CS_FOLQI_MIN)" \
		--out results/evaluate/cs_folqi_qtp_min.parquet --plot results/evaluate/cs_folqi_qtp_min.png

test: $(STAMP)
	$(BIN)/pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_evaluate.py
	$(BIN)/python benchmarks/bench_engine.py

clean:
	rm -rf $(VENV) results build *.egg-info
