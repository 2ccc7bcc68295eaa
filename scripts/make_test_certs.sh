#!/usr/bin/env bash
# Test certificates and credentials for a multi-machine stack (Zenoh TLS with mutual authentication,
# user/password, access control by certificate common name): NOT for production keys.
#
#   scripts/make_test_certs.sh [OUT_DIR] [HOST ...]
#
# OUT_DIR (default certs/test, gitignored) receives, with private files at mode 0600:
#   ca.pem, ca.key                  a fresh certificate authority (CN "AdaptiveH test CA")
#   <id>.pem, <id>.key              one certificate per identity, CN = the identity, signed by the CA:
#                                   learner robot-io vision monitor supervisor router
#   <id>.password                   a random password per identity (zenoh.auth.password_file)
#   usrpwd.txt                      the router's user:password dictionary (zenoh.auth.dictionary_file)
# HOST: names or IP addresses the router is reached by (its certificate's subjectAltName, which clients
# check); localhost and 127.0.0.1 are always included. Example: scripts/make_test_certs.sh certs/lab
# router.lab 192.168.1.10. IDENTITIES="learner vision" overrides the identity list.
# Run it again to replace everything in OUT_DIR (a new CA: certificates of the old one stop working).
set -euo pipefail
OUT=${1:-certs/test}
shift || true
HOSTS=("localhost" "127.0.0.1" "$@")
IDS=${IDENTITIES:-"learner actor robot-io vision monitor supervisor router"}
DAYS=${DAYS:-825}

command -v openssl >/dev/null || { echo "make_test_certs: openssl not found" >&2; exit 1; }
mkdir -p "$OUT"
umask 077
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

san=""
for h in "${HOSTS[@]}"; do
  if [[ $h =~ ^[0-9.]+$ || $h == *:* ]]; then san+="IP:$h,"; else san+="DNS:$h,"; fi
done
san=${san%,}

openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$OUT/ca.key" 2>/dev/null
openssl req -x509 -new -key "$OUT/ca.key" -sha256 -days "$DAYS" -subj "/CN=AdaptiveH test CA" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
  -out "$OUT/ca.pem"

: > "$OUT/usrpwd.txt"
for id in $IDS; do
  [[ $id =~ ^[a-z][a-z0-9_-]*$ ]] || { echo "make_test_certs: bad identity '$id'" >&2; exit 1; }
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$OUT/$id.key" 2>/dev/null
  openssl req -new -key "$OUT/$id.key" -subj "/CN=$id" -out "$tmp/$id.csr"
  # Every identity may both listen and connect (a peer does both), so each certificate carries both
  # usages; the router's SAN holds the hosts clients dial, the others their own name.
  if [[ $id == router ]]; then alt=$san; else alt="DNS:$id"; fi
  cat > "$tmp/$id.ext" <<EOF
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$alt
EOF
  openssl x509 -req -in "$tmp/$id.csr" -CA "$OUT/ca.pem" -CAkey "$OUT/ca.key" -CAcreateserial \
    -CAserial "$tmp/ca.srl" -days "$DAYS" -sha256 -extfile "$tmp/$id.ext" -out "$OUT/$id.pem" 2>/dev/null
  openssl rand -hex 16 > "$OUT/$id.password"
  echo "$id:$(cat "$OUT/$id.password")" >> "$OUT/usrpwd.txt"
done
chmod 644 "$OUT"/*.pem
echo "make_test_certs: CA and identities [$IDS] in $OUT (router hosts: ${HOSTS[*]})"
