// flat_train's run folder before and at the start of writing: what may be
// started in it (fresh, --resume, --overwrite) and how --overwrite replaces
// an old run. The folder's layout is trainer.h's; its paths core/run_dir.h's.
#pragma once
#include <string>

#include "flat/train/trainer.h"

namespace flat::train {

// Checks made before anything is loaded; nothing is changed here. A fresh
// start refuses a folder that holds a run; --overwrite refuses a folder that
// is not a run folder (it may be the user's own files).
void check_run_folder(const std::string& dir, StartMode mode);

// --overwrite: the old run folder goes only now, when the new run has loaded
// everything and is about to write (checked again: it may have changed).
void replace_run_folder(const std::string& dir);

}  // namespace flat::train
