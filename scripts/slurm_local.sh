#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, for the tests and for trying hydra/launcher=slurm locally
# (docs/cluster.md). Debian/Ubuntu, run as root, no systemd needed: the daemons are started directly.
#
#   scripts/slurm_local.sh start    # install what is missing (apt), start munged, MariaDB, slurmdbd, slurmctld,
#                                   # slurmd; return once the node is idle and sacct answers (a no-op if up)
#   scripts/slurm_local.sh status   # exit 0 if the cluster is up (node idle or busy, sacct answers), else 1
#   scripts/slurm_local.sh stop     # stop what start started (munged too, if start started it)
#
# Environment variables (defaults in brackets):
#   AIA_SLURM_DIR      the script's own state: configs, logs, pid files, spool, database [/tmp/aia-slurm]
#   AIA_SLURM_TIMEOUT  seconds each daemon may take to come up [60]
#   AIA_SLURM_DB_PORT  TCP port of the private MariaDB, on 127.0.0.1 only [16033]
#
# Clients (sinfo, sbatch, sacct, submitit) find the config through /etc/slurm/slurm.conf, a link to
# $AIA_SLURM_DIR/etc/slurm.conf that start makes (it refuses to replace a slurm.conf that is not its own).
# Every failure is one line on stderr naming what did not come up and its log, and exit status 1.
set -euo pipefail

STATE=${AIA_SLURM_DIR:-/tmp/aia-slurm}
TIMEOUT=${AIA_SLURM_TIMEOUT:-60}
DB_PORT=${AIA_SLURM_DB_PORT:-16033}
CLUSTER=aia
ETC=$STATE/etc
LOG=$STATE/log
RUN=$STATE/run
DB_DIR=$STATE/mysql
DB_SOCKET=$DB_DIR/mysqld.sock
DB_PASS=aia-local  # the private database listens on 127.0.0.1 only
SYSTEM_CONF=/etc/slurm/slurm.conf
PACKAGES=(slurm-wlm slurmdbd munge mariadb-server)
export SLURM_CONF=$ETC/slurm.conf

die() {
  echo "slurm_local.sh: $*" >&2
  exit 1
}

# wait_for DESCRIPTION LOGFILE COMMAND...: run COMMAND every 0.5 s until it succeeds, or die after $TIMEOUT s.
wait_for() {
  local what=$1 log=$2
  shift 2
  local deadline=$((SECONDS + TIMEOUT))
  until "$@" >/dev/null 2>&1; do
    ((SECONDS < deadline)) || die "$what did not come up in $TIMEOUT s (log: $log)"
    sleep 0.5
  done
}

# running NAME: whether $RUN/NAME.pid names a live process called NAME.
running() {
  local pid
  pid=$(cat "$RUN/$1.pid" 2>/dev/null) || return 1
  [[ -n $pid && "$(cat "/proc/$pid/comm" 2>/dev/null)" == "$1" ]]
}

# spawn NAME COMMAND...: start COMMAND in its own session, detached from the caller's terminal, pipes and
# lock (fd 9: a daemon holding it would block every later start or stop).
spawn() {
  local name=$1
  shift
  setsid "$@" </dev/null >>"$LOG/$name.out" 2>&1 9>&- &
  echo $! >"$RUN/$name.pid"
}

install_packages() {
  local missing=0 binary
  for binary in slurmctld slurmd slurmdbd sacct munged mariadbd mariadb-install-db; do
    command -v "$binary" >/dev/null || missing=1
  done
  ((missing)) || return 0
  [[ $(id -u) == 0 ]] || die "installing ${PACKAGES[*]} needs root"
  command -v apt-get >/dev/null || die "slurm is not installed and there is no apt-get to install it (${PACKAGES[*]})"
  echo "slurm_local.sh: installing ${PACKAGES[*]} (log: $LOG/apt.log)" >&2
  { apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${PACKAGES[@]}"; } \
    >>"$LOG/apt.log" 2>&1 || die "apt-get install ${PACKAGES[*]} failed (log: $LOG/apt.log)"
}

write_configs() {
  local host node
  host=$(hostname -s)
  node=$(slurmd -C | head -n 1)  # NodeName=... CPUs=... RealMemory=...: this machine as slurmd sees it
  [[ $node == NodeName=* ]] || die "slurmd -C did not describe this node: $node"
  mkdir -p "$ETC" "$STATE/spool/ctld" "$STATE/spool/d"
  cat >"$ETC/slurm.conf" <<EOF
# Written by scripts/slurm_local.sh: a single-node cluster without cgroups or job accounting plugins.
ClusterName=$CLUSTER
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=$STATE/spool/ctld
SlurmdSpoolDir=$STATE/spool/d
SlurmctldPidFile=$RUN/slurmctld.pid
SlurmdPidFile=$RUN/slurmd.pid
SlurmctldLogFile=$LOG/slurmctld.log
SlurmdLogFile=$LOG/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=localhost
JobCompType=jobcomp/none
MpiDefault=none
ReturnToService=2
$node NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
  cat >"$ETC/slurmdbd.conf" <<EOF
# Written by scripts/slurm_local.sh: accounting (sacct) in the private MariaDB on 127.0.0.1:$DB_PORT.
AuthType=auth/munge
DbdHost=localhost
SlurmUser=root
LogFile=$LOG/slurmdbd.log
PidFile=$RUN/slurmdbd.pid
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$DB_PORT
StorageUser=slurm
StoragePass=$DB_PASS
StorageLoc=slurm_acct_db
EOF
  chmod 600 "$ETC/slurmdbd.conf"  # slurmdbd refuses a config others can read (it holds the password)
  if [[ -L $SYSTEM_CONF || ! -e $SYSTEM_CONF ]]; then
    mkdir -p "$(dirname "$SYSTEM_CONF")"
    ln -sfn "$ETC/slurm.conf" "$SYSTEM_CONF"
  elif [[ "$(realpath "$SYSTEM_CONF")" != "$(realpath "$ETC/slurm.conf")" ]]; then
    die "$SYSTEM_CONF exists and is not this script's; move it away to run a local cluster"
  fi
}

munge_works() {
  munge -n | unmunge
}

start_munge() {
  munge_works >/dev/null 2>&1 && return 0
  if [[ ! -s /etc/munge/munge.key ]]; then
    dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
    chown munge:munge /etc/munge/munge.key
    chmod 400 /etc/munge/munge.key
  fi
  mkdir -p /run/munge "$STATE/munge"
  chown munge:munge /run/munge "$STATE/munge"
  chmod 700 "$STATE/munge"
  runuser -u munge -- munged --pid-file="$STATE/munge/munged.pid" --log-file="$STATE/munge/munged.log" \
    </dev/null >>"$LOG/munged.out" 2>&1 9>&- || die "munged did not start (log: $STATE/munge/munged.log)"
  ln -sfn "$STATE/munge/munged.pid" "$RUN/munged.pid"  # munged writes it; stop reads it from $RUN
  wait_for munged "$STATE/munge/munged.log" munge_works
}

db() {
  mariadb --no-defaults --socket="$DB_SOCKET" --user=root "$@"
}

start_database() {
  if ! running mariadbd; then
    if [[ ! -d $DB_DIR/data/mysql ]]; then
      mkdir -p "$DB_DIR"
      chown mysql:mysql "$DB_DIR"
      mariadb-install-db --no-defaults --user=mysql --datadir="$DB_DIR/data" --auth-root-authentication-method=socket \
        --skip-test-db >>"$LOG/mariadb-install.log" 2>&1 || die "mariadb-install-db failed (log: $LOG/mariadb-install.log)"
    fi
    spawn mariadbd mariadbd --no-defaults --user=mysql --datadir="$DB_DIR/data" --socket="$DB_SOCKET" \
      --bind-address=127.0.0.1 --port="$DB_PORT" --skip-name-resolve --innodb-buffer-pool-size=32M \
      --log-error="$LOG/mariadb.log"
  fi
  wait_for MariaDB "$LOG/mariadb.log" db -e "SELECT 1"
  db -e "CREATE USER IF NOT EXISTS 'slurm'@'127.0.0.1' IDENTIFIED BY '$DB_PASS';
         GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';" || die "could not create the slurm database user"
}

cluster_registered() {
  sacctmgr --noheader --parsable2 list cluster format=cluster | grep -qx "$CLUSTER"
}

node_state() {
  sinfo --noheader --Node --format=%t 2>/dev/null | head -n 1
}

node_up() {
  [[ "$(node_state)" =~ ^(idle|mix|alloc)$ ]]
}

sacct_answers() {
  sacct --noheader --allocations --starttime=now-1hours
}

start() {
  mkdir -p "$STATE" "$LOG" "$RUN"
  exec 9>"$STATE/lock"
  flock 9  # one start or stop at a time
  install_packages
  write_configs
  start_munge
  start_database
  if ! running slurmdbd; then
    spawn slurmdbd slurmdbd -D
  fi
  wait_for slurmdbd "$LOG/slurmdbd.log" sacctmgr --noheader list cluster
  cluster_registered || sacctmgr --immediate add cluster "$CLUSTER" >>"$LOG/sacctmgr.log" 2>&1 \
    || die "sacctmgr could not register cluster $CLUSTER (log: $LOG/sacctmgr.log)"
  running slurmctld || spawn slurmctld slurmctld -D
  running slurmd || spawn slurmd slurmd -D
  wait_for "node $(hostname -s)" "$LOG/slurmctld.log, $LOG/slurmd.log" node_up
  wait_for sacct "$LOG/slurmdbd.log" sacct_answers
}

# stop_daemons NAME...: SIGTERM the daemons named by $RUN/NAME.pid, all at once, and wait for them to exit
# (SIGKILL after 20 s).
stop_daemons() {
  local name pids=()
  for name in "$@"; do
    if running "$name"; then
      pids+=("$(cat "$RUN/$name.pid")")
      kill "${pids[-1]}"
    fi
    rm -f "$RUN/$name.pid"
  done
  local pid deadline=$((SECONDS + 20))
  for pid in "${pids[@]}"; do
    while kill -0 "$pid" 2>/dev/null; do
      if ((SECONDS >= deadline)); then
        kill -9 "$pid" 2>/dev/null || true
        break
      fi
      sleep 0.2
    done
  done
}

stop() {
  [[ -d $STATE ]] || return 0
  exec 9>"$STATE/lock"
  flock 9
  stop_daemons slurmd slurmctld slurmdbd mariadbd munged  # munged only if start started it
  [[ -L $SYSTEM_CONF && "$(readlink "$SYSTEM_CONF")" == "$ETC/slurm.conf" ]] && rm -f "$SYSTEM_CONF"
  return 0
}

status() {
  local name
  for name in slurmdbd slurmctld slurmd; do
    running "$name" || { echo "slurm_local.sh: $name is not running"; return 1; }
  done
  node_up || { echo "slurm_local.sh: the node is not up (sinfo: '$(node_state)')"; return 1; }
  sacct_answers >/dev/null 2>&1 || { echo "slurm_local.sh: sacct does not answer"; return 1; }
  echo "slurm_local.sh: up (node $(node_state), state in $STATE)"
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  status) status ;;
  *)
    echo "usage: $0 start|stop|status" >&2
    exit 2
    ;;
esac
