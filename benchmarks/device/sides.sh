# Sourced by the device scripts that compare two revisions in one call (vector_lockstep.sh,
# step_before_after.sh): archive_sides ROOT BEFORE AFTER DIR SCRIPT puts BEFORE's and AFTER's committed
# src/ in DIR/src-before and DIR/src-after, AFTER's benchmarks/SCRIPT in DIR, and both short hashes in DIR/REVS.
archive_sides() {
  local root="$1" before="$2" after="$3" dir="$4" script="$5"
  (cd "$root" && git archive "$before" src | tar -x -C "$dir" --transform 's,^src,src-before,' \
    && git archive "$after" src | tar -x -C "$dir" --transform 's,^src,src-after,' \
    && git show "$after:benchmarks/$script" > "$dir/$script" \
    && echo "before $(git rev-parse --short "$before") after $(git rev-parse --short "$after")" > "$dir/REVS")
}
