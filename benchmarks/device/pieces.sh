# shellcheck shell=bash
# Packages cut into pieces for the lent GPU machine (sourced by libero_warp_upload.sh and metaworld_upload.sh).
# A device call carries at most 64 MiB, the checkout included, so a package travels as one xz tar cut into pieces,
# one directory per call (DIR/c01 .. DIR/cNN; c01 also holds the count and the SHA256), received one call at a
# time into a directory there and unpacked by the last call.
CHUNK_BYTES="${CHUNK_BYTES:-60000000}"  # at most; piece_bytes lowers it for the checkout at hand

mb() { du -sb "$@" | awk '{s += $1} END {printf "%.1f MB", s / 1e6}'; }

# a piece travels with the whole checkout (tracked and untracked-not-ignored files): 64 MiB less that, less 1 MiB.
# The device tool counts a file as the disk blocks it takes (4 KiB each: 718 files of 9.04 MB came to 10.3 MB in
# December, and a piece cut from the bytes alone was refused), so each file is counted rounded up to 4 KiB.
piece_bytes() {  # ROOT
  local tree room
  tree=$(cd "$1" && { git ls-files -z; git ls-files -z --others --exclude-standard; } | xargs -0 stat -c %s 2>/dev/null \
    | awk '{s += int(($1 + 4095) / 4096) * 4096} END {print s + 0}')
  room=$(( (64 << 20) - tree - (1 << 20) ))
  echo $(( room < CHUNK_BYTES ? room : CHUNK_BYTES ))
}

_deal_pieces() {  # DIR: DIR/pkg.part* into DIR/c01 .. cNN (c01 keeps what is already there)
  local dir="$1" i=0 part
  mkdir -p "$dir/c01"
  ls "$dir"/pkg.part* | wc -l > "$dir/c01/pkg.count"
  for part in "$dir"/pkg.part*; do
    i=$((i + 1)); mkdir -p "$dir/c$(printf %02d $i)"; mv "$part" "$dir/c$(printf %02d $i)/"
  done
  echo "$i"
}

# DIR/stage as one xz tar, split into pieces of CHUNK_BYTES, one directory per device call
pack() {  # DIR
  local dir="$1" n
  tar -C "$dir/stage" -cf - . | xz -T0 -9 > "$dir/pkg.tar.xz"
  split -b "$CHUNK_BYTES" -d -a 2 "$dir/pkg.tar.xz" "$dir/pkg.part"
  mkdir -p "$dir/c01"
  sha256sum "$dir/pkg.tar.xz" | awk '{print $1}' > "$dir/c01/pkg.sha256"
  n=$(_deal_pieces "$dir")
  echo "packed $(mb "$dir/stage") into $(mb "$dir/pkg.tar.xz") (xz): $n piece(s) of at most $CHUNK_BYTES bytes, $n device call(s)"
  rm -rf "$dir/stage" "$dir/pkg.tar.xz"
}

# the pieces already in DIR (c01 .. cNN) cut again for the checkout at hand (it grew: a piece no longer fits)
recut() {  # DIR
  local dir="$1" n
  CHUNK_BYTES=$(piece_bytes "$(git rev-parse --show-toplevel)")
  cat "$dir"/c*/pkg.part* > "$dir/pkg.tar.xz"
  [ "$(sha256sum "$dir/pkg.tar.xz" | awk '{print $1}')" = "$(cat "$dir/c01/pkg.sha256")" ] \
    || { echo "recut: the pieces in $dir do not match their SHA256" >&2; exit 2; }
  cp "$dir/c01/pkg.sha256" "$dir/pkg.sha256"
  rm -rf "$dir"/c[0-9]*
  split -b "$CHUNK_BYTES" -d -a 2 "$dir/pkg.tar.xz" "$dir/pkg.part"
  mkdir -p "$dir/c01"
  mv "$dir/pkg.sha256" "$dir/c01/"
  n=$(_deal_pieces "$dir")
  rm -f "$dir/pkg.tar.xz"
  echo "recut into $n piece(s) of at most $CHUNK_BYTES bytes, $n device call(s)"
}

receive_pieces() {  # SRC IN: one call's directory (DIR/ck) copied into IN
  [ -d "${1:-}" ] || { echo "receive: no piece directory ${1:-}" >&2; exit 2; }
  mkdir -p "$2"; cp -r "$1"/. "$2/"
  echo "received $(ls "$2"/pkg.part* 2>/dev/null | wc -l) piece(s) of $(cat "$2/pkg.count" 2>/dev/null || echo '?') in $2"
}

unpack_pieces() {  # IN DEST: every piece there, their SHA256 checked, unpacked into DEST
  local have want
  [ -f "$1/pkg.count" ] && [ -f "$1/pkg.sha256" ] \
    || { echo "install: the first piece (c01: count and SHA256) was not received" >&2; exit 2; }
  have=$(ls "$1"/pkg.part* 2>/dev/null | wc -l); want=$(cat "$1/pkg.count")
  [ "$have" = "$want" ] || { echo "install: $have of $want pieces received ($(cd "$1" && ls pkg.part* | tr '\n' ' '))" >&2; exit 2; }
  [ "$(cat "$1"/pkg.part* | sha256sum | awk '{print $1}')" = "$(cat "$1/pkg.sha256")" ] \
    || { echo "install: SHA256 mismatch" >&2; exit 2; }
  mkdir -p "$2"; cat "$1"/pkg.part* | xz -dc | tar -x -C "$2"
}

# A Warp kernel cache (a WARP_CACHE_PATH) between machines: brought back as one xz tar cut into NAME.txz.NN files of
# 15 MB in OUT (the largest the device tool brings back), received on the next machine like a piece and unpacked
# into its WARP_CACHE_PATH before the first run, which then loads those kernels instead of compiling them.
cache_back() {  # SRC OUT NAME [MAX_BYTES]: nothing written (and 1 returned) when the tar is larger than MAX_BYTES
  XZ_OPT="-T0 -6" timeout 60 tar -C "$1" -cJf "/tmp/$3.txz" . || return 1
  if [ -n "${4:-}" ] && [ "$(stat -c %s "/tmp/$3.txz")" -gt "$4" ]; then
    echo "kernel cache $3: $(mb "/tmp/$3.txz"), more than $4 bytes: not brought back" >&2; return 1
  fi
  split -b 15000000 -d "/tmp/$3.txz" "$2/$3.txz." && ls -l "$2/$3".txz.*
}

cache_in() {  # IN NAME DEST: the NAME.txz.NN received into IN unpacked into DEST (none received: nothing done)
  compgen -G "$1/$2.txz.*" > /dev/null || return 0
  mkdir -p "$3" && cat "$1/$2".txz.* | tar -C "$3" -xJf - && echo "kernel cache: $2"
}
