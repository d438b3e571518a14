// Compiled once to build the precompiled header (src/pch.h).
