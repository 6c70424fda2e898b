#!/usr/bin/env bash
# A user's start script: runs the stack and passes no arguments on (so --ros-args never reach it).
exec "${PYTHON:-python3}" "$(dirname "$0")/own_names_stack.py"
