# shellcheck shell=bash
# A benchmark backend made to look provisioned on the lent GPU machine (sourced by libero_warp_upload.sh and
# metaworld_upload.sh): there is no registry there, so the packages travel as unpacked wheels and simseam's
# `provision.venv_dir(NAME)` gets a bin/python that runs the machine's interpreter with them first on its path,
# and the simseam-backend.json that says the venv is there; then, as provisioning does, its catalog is asked once
# and kept there (the first `simseam eval` on the machine would otherwise pay for it: ~5 s for Meta-World).
standin_backend() {  # NAME PY PATHS [ASSIGNMENT...]: prints the venv; PATHS colon-joined, ASSIGNMENTs exported too
  local name="$1" py="$2" paths="$3" venv
  shift 3
  venv="$("$py" -c 'import sys; from simseam.backends.provision import venv_dir; print(venv_dir(sys.argv[1]))' "$name")"
  mkdir -p "$venv/bin"
  printf '#!/bin/sh\nexport PYTHONPATH="%s${PYTHONPATH:+:$PYTHONPATH}"%s\nexec %s "$@"\n' "$paths" "${*:+ $*}" "$py" \
    > "$venv/bin/python"
  chmod +x "$venv/bin/python"
  "$py" -c 'import json, sys; json.dump({"name": sys.argv[2], "python": sys.argv[3]}, open(sys.argv[1], "w"))' \
    "$venv/simseam-backend.json" "$name" "$py + $paths (a stand-in on the device machine)"
  "$py" -c 'import sys; from simseam.backends.provision import catalog; catalog(sys.argv[1])' "$name" >&2 \
    || echo "standin_backend: $name's tasks not listed yet (a run asks again)" >&2
  echo "$venv"
}
