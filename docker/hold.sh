#!/bin/sh
# sqpmpc-hold CMD...: run CMD, then keep the container up until the stack stops.
#
# `docker compose up --exit-code-from plant` stops the whole stack as soon as ANY container
# exits (docker/compose#13800), so the one-shot credentials step, and the robots (which leave
# on the plant's 'done', before the plant has written its outputs), would end the demo
# early. Under this wrapper they stay up after their command; the plant's own exit ends the
# stack, and compose returns the plant's status. The command's status is kept in
# $SQPMPC_HOLD_STATUS (default /tmp/sqpmpc-status; the healthcheck reads it) and is this
# script's exit status when the stack stops it. A failing command still shows: its
# container turns unhealthy.
"$@" &
child=$!
# a stop while the command runs is passed on to it (init forwards signals to this shell
# only), and once the command has ended this script ends too: a stopped stack does not wait
# for its grace period on a container that went back to holding
stopped=0
trap 'stopped=1; kill -TERM "$child" 2>/dev/null' TERM INT
wait "$child"
status=$?
if [ "$stopped" = 1 ]; then  # that wait was cut short by the signal: the command's own status
    wait "$child"
    status=$?
fi
while kill -0 "$child" 2>/dev/null; do  # woken by a signal: wait for the command itself
    wait "$child"
    status=$?
done
echo "$status" > "${SQPMPC_HOLD_STATUS:-/tmp/sqpmpc-status}"
if [ "$stopped" = 1 ]; then
    exit "$status"
fi
trap 'exit "$status"' TERM INT
echo "$1 $2 $3 exited with status $status; holding until the stack stops"
while :; do
    sleep 3600 &
    wait $!
done
