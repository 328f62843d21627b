#!/usr/bin/env bash
# Generate a project CA and one certificate per mimic service (mutual TLS for Zenoh).
#
#   deploy/secure/make-certs.sh [OUT_DIR] [ROUTER_HOST ...]
#
# OUT_DIR defaults to deploy/secure/certs (git-ignored). Each service gets
# <name>.pem + <name>.key with CN=<name>: the router's access_control matches
# that CN (cert_common_names). The router certificate carries ROUTER_HOST
# names/IPs as subjectAltName (default: localhost 127.0.0.1) so clients can
# verify its name. Private keys are written 0600 and must never be committed.
# It also renders router.json5 and <service>.json5 (Zenoh configs with absolute
# paths) next to the certificates; MIMIC_ROUTER_ENDPOINT overrides the
# endpoint services connect to (default tls/<first ROUTER_HOST>:7447) and
# MIMIC_CERTS_PATH the directory the configs name (default OUT_DIR itself; in
# containers the folder OUT_DIR is mounted at, e.g. /certs).
# Existing CA files are reused, so re-running adds missing service certs.
set -euo pipefail

HERE="$(cd "$(dirname "$0")" && pwd)"
OUT="${1:-$HERE/certs}"
shift || true
HOSTS=("$@")
[ ${#HOSTS[@]} -eq 0 ] && HOSTS=(localhost 127.0.0.1)
SERVICES=(${MIMIC_CERT_SERVICES:-ingest retarget solver sim logger recorder replay launcher operator})
DAYS="${MIMIC_CERT_DAYS:-825}"

mkdir -p "$OUT"
umask 077
cd "$OUT"

if [ ! -f ca.key ]; then
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days "$DAYS" \
    -subj "/CN=mimic-ca" -keyout ca.key -out ca.pem \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
fi

san=""
for h in "${HOSTS[@]}"; do
  if [[ "$h" =~ ^[0-9.]+$ || "$h" == *:* ]]; then san+="IP:$h,"; else san+="DNS:$h,"; fi
done
san="${san%,}"

issue() {  # issue NAME EXT_USAGE [SAN]
  local name="$1" usage="$2" alt="${3:-}"
  [ -f "$name.pem" ] && return 0
  local ext
  ext="$(mktemp)"
  {
    echo "basicConstraints=critical,CA:FALSE"
    echo "keyUsage=critical,digitalSignature"
    echo "extendedKeyUsage=$usage"
    [ -n "$alt" ] && echo "subjectAltName=$alt"
  } > "$ext"
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -subj "/CN=$name" \
    -keyout "$name.key" -out "$name.csr" 2>/dev/null
  openssl x509 -req -in "$name.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days "$DAYS" \
    -extfile "$ext" -out "$name.pem" 2>/dev/null
  rm -f "$name.csr" "$ext"
}

issue router "serverAuth,clientAuth" "$san"
for s in "${SERVICES[@]}"; do
  # Services are clients of the router; the SAN lets the same cert serve a peer listener too.
  issue "$s" "clientAuth,serverAuth" "DNS:$s"
done
chmod 600 ./*.key
chmod 644 ./*.pem

# Render the Zenoh configs with absolute certificate paths.
CERTS="${MIMIC_CERTS_PATH:-$(pwd)}"
ROUTER_ENDPOINT="${MIMIC_ROUTER_ENDPOINT:-tls/${HOSTS[0]}:7447}"
sed "s|@CERTS@|$CERTS|g" "$HERE/router.template.json5" > router.json5
for s in "${SERVICES[@]}"; do
  sed -e "s|@CERTS@|$CERTS|g" -e "s|@NAME@|$s|g" -e "s|@ROUTER_ENDPOINT@|$ROUTER_ENDPOINT|g" \
    "$HERE/client.template.json5" > "$s.json5"
done
echo "certificates and configs in $CERTS: router.json5, <service>.json5 for ${SERVICES[*]}" >&2
