#!/bin/sh
# Certificates for Zenoh mutual TLS (deploy/zenoh/peer-mtls.json5, peer-acl.json5): one CA per
# camera network, one certificate + key per box, signed by that CA.
#
#   deploy/tls/make-certs.sh OUT_DIR NAME[=SAN[,SAN...]] ...
#
#   deploy/tls/make-certs.sh /tmp/tls cam0=IP:192.168.1.10 cam1=IP:192.168.1.11 \
#                                     cam2=IP:192.168.1.12,DNS:cam2.lan
#   deploy/tls/make-certs.sh /tmp/tls cam0 cam1          # SAN defaults to IP:127.0.0.1 (tests)
#
# Writes OUT_DIR/ca.pem and ca.key (the CA; created once, reused when present, so boxes can be
# added later) and OUT_DIR/NAME.pem, NAME.key for every NAME. NAME is the certificate's common
# name (CN): the name access control matches (access_control subjects cert_common_names).
# The SAN must hold the address the neighbours connect to (tls/<that address>:port): Zenoh
# verifies it. Install on box NAME: ca.pem, NAME.pem -> box.pem, NAME.key -> box.key (mode 0600).
# Keep ca.key off the boxes.
#
# Environment: DAYS (certificate lifetime, default 825), CA_CN (default "dmtt-ca"),
# OPENSSL (default "openssl"). Keys are ECDSA P-256 in PKCS#8.
set -eu

OPENSSL=${OPENSSL:-openssl}
DAYS=${DAYS:-825}
CA_CN=${CA_CN:-dmtt-ca}

if [ "$#" -lt 2 ]; then
    sed -n '2,19p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
fi
OUT=$1
shift
mkdir -p "$OUT"
umask 077
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT INT TERM

if [ ! -f "$OUT/ca.pem" ] || [ ! -f "$OUT/ca.key" ]; then
    "$OPENSSL" genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$OUT/ca.key"
    cat > "$TMP/ca.ext" <<EOF
[req]
distinguished_name = dn
x509_extensions = v3_ca
prompt = no
[dn]
CN = $CA_CN
[v3_ca]
basicConstraints = critical, CA:TRUE
keyUsage = critical, keyCertSign, cRLSign
subjectKeyIdentifier = hash
EOF
    "$OPENSSL" req -x509 -new -key "$OUT/ca.key" -sha256 -days "$DAYS" -config "$TMP/ca.ext" \
        -out "$OUT/ca.pem"
    echo "CA: $OUT/ca.pem (CN=$CA_CN)"
fi

for spec in "$@"; do
    name=${spec%%=*}
    if [ "$name" = "$spec" ]; then san="IP:127.0.0.1"; else san=${spec#*=}; fi
    case $name in
        ''|*/*|*' '*|ca) echo "make-certs.sh: bad box name '$name'" >&2; exit 2 ;;
    esac
    cat > "$TMP/$name.ext" <<EOF
basicConstraints = critical, CA:FALSE
keyUsage = critical, digitalSignature, keyEncipherment
extendedKeyUsage = serverAuth, clientAuth
subjectAltName = $san
subjectKeyIdentifier = hash
authorityKeyIdentifier = keyid
EOF
    "$OPENSSL" genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$OUT/$name.key"
    "$OPENSSL" req -new -key "$OUT/$name.key" -subj "/CN=$name" -out "$TMP/$name.csr"
    # every box is both a TLS server (it listens) and a client (it connects): both usages
    "$OPENSSL" x509 -req -in "$TMP/$name.csr" -CA "$OUT/ca.pem" -CAkey "$OUT/ca.key" \
        -set_serial "0x$("$OPENSSL" rand -hex 16)" -sha256 -days "$DAYS" -extfile "$TMP/$name.ext" \
        -out "$OUT/$name.pem" 2>/dev/null
    echo "$name: $OUT/$name.pem, $OUT/$name.key (CN=$name, SAN $san)"
done
