#!/usr/bin/env bash
# scripts/install-deps.sh as README's first command runs it, with apt-get, dpkg-query and sudo
# replaced by stubs that record their calls (every package reported missing): as root it must
# call apt-get itself and never sudo (a fresh Debian has no sudo); as another user it must go
# through sudo. The second case runs when this test runs as root (setpriv drops to nobody) or
# as a user.
set -euo pipefail
script="$(cd "$(dirname "$0")/../.." && pwd)/scripts/install-deps.sh"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
chmod 755 "$work"
mkdir "$work/stubs"
log="$work/calls.log"
: >"$log"
chmod 666 "$log"
cat >"$work/stubs/dpkg-query" <<STUB
#!/bin/sh
exit 1
STUB
cat >"$work/stubs/apt-get" <<STUB
#!/bin/sh
echo "apt-get \$*" >>"$log"
STUB
cat >"$work/stubs/sudo" <<STUB
#!/bin/sh
echo "sudo \$*" >>"$log"
STUB
chmod 755 "$work/stubs"/*
cp "$script" "$work/install-deps.sh"
chmod 755 "$work/install-deps.sh"

fail() { echo "FAIL: $*" >&2; cat "$log" >&2; exit 1; }

run_as_root() {
  : >"$log"
  PATH="$work/stubs:/usr/bin:/bin" bash "$work/install-deps.sh" >/dev/null
  grep -q '^apt-get update' "$log" || fail "as root: apt-get update was not called"
  grep -q '^apt-get install -y --no-install-recommends .*libcurl4-openssl-dev' "$log" ||
    fail "as root: apt-get install was not called with the packages"
  if grep -q '^sudo' "$log"; then fail "as root: sudo was called"; fi
  echo "as root: apt-get called directly, sudo never"
}

run_as_user() {
  : >"$log"
  "$@" env PATH="$work/stubs:/usr/bin:/bin" bash "$work/install-deps.sh" >/dev/null
  grep -q '^sudo apt-get update' "$log" || fail "as a user: not through sudo"
  if grep -q '^apt-get' "$log"; then fail "as a user: apt-get called without sudo"; fi
  echo "as a user: apt-get through sudo"
}

if [ "$(id -u)" -eq 0 ]; then
  run_as_root
  if command -v setpriv >/dev/null; then
    run_as_user setpriv --reuid=65534 --regid=65534 --clear-groups
  fi
else
  run_as_user
fi
