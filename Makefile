# Two entry points for a fresh machine: `make demo` and `make test`.
# Both create .venv and install everything on first use (system packages too).
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
export MUJOCO_GL ?= osmesa
export PYOPENGL_PLATFORM ?= osmesa

.PHONY: demo test test-ray lint docs system-deps clean reproduce publish publish-screen subspaces archive restore publish-docs

$(STAMP): pyproject.toml scripts/install-system-deps.sh
	bash scripts/install-system-deps.sh
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/pved demo

# The paper's protocol on one pair with every method: make reproduce PAIR=reacher BUDGET=quick
# (WORKERS=1 leaves the other cores free; rerunning the same command resumes;
# FROM=quick first copies the finished policies, pairs, models and banks of
# reports/<pair>-quick, which a paper-budget protocol would otherwise make again;
# BUDGET=paper-wide FROM=paper also copies the paper protocol's transfer runs, so only
# the 66 new evaluation runs a method are made; METHODS="pved ppo" narrows it)
PAIR    ?= reacher
BUDGET  ?= quick
METHODS ?= pved pved-state-only pved-shared-only pved-det-shared pved-vae gupta2017 ppo oracle
reproduce: $(STAMP)
	$(VENV)/bin/pved protocol --pair $(PAIR) --budget $(BUDGET) --methods $(METHODS) \
		--out reports/$(PAIR)-$(BUDGET) $(if $(WORKERS),--workers $(WORKERS)) \
		$(if $(FROM),--stages-from reports/$(PAIR)-$(FROM))

# A protocol outlives the machine it runs on: `make archive` copies its finished runs,
# slimmed (results, configs, curves, models; no checkpoints, datasets or banks), into
# archive/<pair>-<budget>/ (kept beside the repository, not committed), and writes the
# committed record, docs/protocol/<pair>-<budget>/finished-transfer-runs.json (each finished
# transfer run's result, config and curve); `make restore` puts back into
# reports/<pair>-<budget>/ what either holds (for a published pair, its summary too, so it
# reads as finished), and `make reproduce` then goes on with the rest.
archive: $(STAMP)
	$(VENV)/bin/pved archive save --protocol reports/$(PAIR)-$(BUDGET) \
		--archive archive/$(PAIR)-$(BUDGET)
	$(VENV)/bin/pved archive summary --protocol reports/$(PAIR)-$(BUDGET) \
		--archive docs/protocol/$(PAIR)-$(BUDGET)
restore: $(STAMP)
	$(if $(wildcard archive/$(PAIR)-$(BUDGET)),$(VENV)/bin/pved archive restore \
		--archive archive/$(PAIR)-$(BUDGET) --protocol reports/$(PAIR)-$(BUDGET))
	$(VENV)/bin/pved archive restore --archive docs/protocol/$(PAIR)-$(BUDGET) \
		--protocol reports/$(PAIR)-$(BUDGET)

# "What the subspaces learned" for a finished protocol (`pved analyze`, pved.diagnostics):
# t-SNE, bound and the HTML report of PVED's best evaluation run (subspaces), the scale of
# Eq. 10's distance on the training pairs (shaping-scale), how much the pairing and the
# models' shared codes relate the two agents (pairing-signal) and each shaped method by
# source policy (source-reading), into reports/<pair>-<budget>/subspaces/; for jaco-fetch
# also where on the table each evaluation run's policy succeeds (peg-success)
subspaces: $(STAMP)
	$(VENV)/bin/pved analyze subspaces reports/$(PAIR)-$(BUDGET)
	$(VENV)/bin/pved analyze shaping-scale reports/$(PAIR)-$(BUDGET)
	$(VENV)/bin/pved analyze pairing-signal reports/$(PAIR)-$(BUDGET)
	$(VENV)/bin/pved analyze source-reading reports/$(PAIR)-$(BUDGET)
	$(if $(filter jaco-fetch,$(PAIR)),$(VENV)/bin/pved analyze peg-success \
		reports/$(PAIR)-$(BUDGET) --copies 4)

# Copy a finished protocol's summaries and figures (not its runs or HTML) into docs/protocol/,
# where they are committed, then judge the paper's claims on every finished pair (one
# whose protocol is still running has no summary.json yet and is left out): from its runs
# under reports/ where they are here, else from its published summary (whose runs' curves,
# and so the early and stability scores, are not there).
FINISHED_HERE = $(patsubst %/summary.json,%,$(wildcard reports/*-$(BUDGET)/summary.json))
PUBLISHED_ONLY = $(foreach d,$(patsubst %/summary.json,%,$(wildcard docs/protocol/*-$(BUDGET)/summary.json)),\
	$(if $(filter $(notdir $(d)),$(notdir $(FINISHED_HERE))),,$(d)))
publish:
	mkdir -p docs/protocol/$(PAIR)-$(BUDGET)
	cp reports/$(PAIR)-$(BUDGET)/protocol.json reports/$(PAIR)-$(BUDGET)/selection.json \
		reports/$(PAIR)-$(BUDGET)/summary.json reports/$(PAIR)-$(BUDGET)/summary.md \
		reports/$(PAIR)-$(BUDGET)/curves-$(PAIR).png docs/protocol/$(PAIR)-$(BUDGET)/
	if [ -d reports/$(PAIR)-$(BUDGET)/subspaces ]; then \
		mkdir -p docs/protocol/$(PAIR)-$(BUDGET)/subspaces && \
		cp reports/$(PAIR)-$(BUDGET)/subspaces/tsne/* reports/$(PAIR)-$(BUDGET)/subspaces/bound.txt \
			reports/$(PAIR)-$(BUDGET)/subspaces/chosen.json \
			reports/$(PAIR)-$(BUDGET)/subspaces/shaping_scale.json \
			reports/$(PAIR)-$(BUDGET)/subspaces/pairing_signal.json \
			reports/$(PAIR)-$(BUDGET)/subspaces/source_reading.json \
			docs/protocol/$(PAIR)-$(BUDGET)/subspaces/; fi
	if [ -f reports/$(PAIR)-$(BUDGET)/subspaces/peg_success.json ]; then \
		cp reports/$(PAIR)-$(BUDGET)/subspaces/peg_success.json \
			docs/protocol/$(PAIR)-$(BUDGET)/subspaces/; fi
	$(PY) scripts/relative_record_paths.py  # paths a summary of an older pved left absolute
	$(VENV)/bin/pved claims $(FINISHED_HERE) $(PUBLISHED_ONLY) --out docs/protocol/claims-$(BUDGET)

# Every table of results in README.md, docs/results.md and docs/results/<pair>.md, made
# anew from the committed records in docs/protocol/ (`pved publish`; run it after `make
# publish` or `make publish-screen`); `pved publish --check` says whether any page is stale.
publish-docs: $(STAMP)
	$(VENV)/bin/pved publish

# A screen of a method beyond the paper (a protocol of that method and ppo, in
# reports/<SCREEN>/): its summaries, curves and runs' record into docs/protocol/<SCREEN>/,
# and the method against ppo there (pved scoreboard), e.g.
# make publish-screen SCREEN=humanoid-ant-quick-align METHOD=pved-align
publish-screen: $(STAMP)
	test -n "$(SCREEN)" -a -n "$(METHOD)" -a -f reports/$(SCREEN)/summary.json || \
		{ echo "publish-screen needs SCREEN=<finished reports/ dir> METHOD=<method>" >&2; exit 2; }
	mkdir -p docs/protocol/$(SCREEN)
	cp reports/$(SCREEN)/protocol.json reports/$(SCREEN)/selection.json \
		reports/$(SCREEN)/summary.json reports/$(SCREEN)/summary.md \
		reports/$(SCREEN)/curves-*.png docs/protocol/$(SCREEN)/
	$(PY) scripts/relative_record_paths.py  # paths a summary of an older pved left absolute
	$(VENV)/bin/pved archive summary --protocol reports/$(SCREEN) --archive docs/protocol/$(SCREEN)
	$(VENV)/bin/pved scoreboard --method $(METHOD) docs/protocol/$(SCREEN) --out docs/protocol/$(SCREEN)

test: $(STAMP) lint docs
	$(PY) -m pytest -q

# A spec pair's protocol on a Ray cluster of two nodes that loses one part-way
# (tests/test_ray_cluster.py; about two minutes of two cores, so not in `make test`)
test-ray: $(STAMP)
	PVED_RAY_CLUSTER_TESTS=1 $(PY) -m pytest -q tests/test_ray_cluster.py

# The documentation site (mkdocs.yml: docs/ and the docstrings into site/), offline, in
# seconds; warnings are errors, so a broken link or anchor, a page missing from the nav's
# files or a docstring mkdocstrings cannot read fails it. (The variable silences a notice
# the theme prints on every build.)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks scripts
	$(VENV)/bin/ruff format --check src tests benchmarks scripts
	$(VENV)/bin/mypy

clean:
	rm -rf $(VENV) runs reports site
