# Sourced by the benchmark scripts: figures of a running process, read from /proc.

# CPU seconds (user + system) of process $1 so far.
cpu_s() { awk -v hz="$(getconf CLK_TCK)" '{ sub(/^.*\) /, ""); print ($12 + $13) / hz }' "/proc/$1/stat"; }
