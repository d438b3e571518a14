#!/usr/bin/env bash
# Sourced by the GPU scripts: the frame size and frame count of each stage of
# the paper's schedule, as configs/stageN.yaml train them.
#   stage_sizes N   sets `size` (HxW) and `frames`; fails on an unknown stage.
stage_sizes() {
  case $1 in
    1) size=176x320; frames=17 ;;
    2) size=176x320; frames=49 ;;
    3) size=360x640; frames=49 ;;
    4) size=432x768; frames=49 ;;
    *) echo "unknown stage '$1' (1-4)" >&2; return 1 ;;
  esac
}
