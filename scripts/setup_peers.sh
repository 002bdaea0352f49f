#!/usr/bin/env bash
# Installs the peer optimisers (GTSAM and g2o's Python bindings, pinned in
# ../shared/peers/requirements.txt) into .venv/ at the repository root, for
# scripts/bench_speed.py and scripts/bench_robust.py. CI does not run this.
#
# usage: scripts/setup_peers.sh [PEERS_DIR]   (default: $PGO_PEERS or ../shared/peers)
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PEERS=${1:-${PGO_PEERS:-$ROOT/../shared/peers}}
[[ -f $PEERS/requirements.txt ]] || { echo "no requirements.txt in $PEERS (set PGO_PEERS)" >&2; exit 2; }
python3 -m venv "$ROOT/.venv"
"$ROOT/.venv/bin/pip" install -q --upgrade pip
"$ROOT/.venv/bin/pip" install -q -r "$PEERS/requirements.txt"
"$ROOT/.venv/bin/python" -c "import gtsam, g2opy, numpy; print('peers ready: gtsam', gtsam.__version__ if hasattr(gtsam, '__version__') else '', '| g2opy | numpy', numpy.__version__)"
