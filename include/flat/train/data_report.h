// What the trainer's data amount to, said before the first step: per dataset
// the scenes used and why the rest were left out (data/loader.h), how many
// carry depth and normals, and the effective batch; a depth or normal term
// with no targets refuses to train (loss.missing_geometry: fail).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/data/loader.h"
#include "flat/loss/objective.h"

namespace flat::train {

// Throws (fail) or warns when lambda_depth / lambda_normal is set and no
// training scene has depth / normals; warns when only some have them.
void check_geometry_targets(const loss::LossConfig& loss, const data::Loader& train);

// The same as lines for the log (the run's train.log gets them once the run
// folder exists): the totals, then one line per dataset.
std::vector<std::string> data_summary(const data::Loader& train, const data::Loader* val, int64_t world_size,
                                      int64_t batch_per_rank);

// data_report.json of the run folder (val may be null).
std::string data_report_json(const data::Loader& train, const data::Loader* val, int64_t world_size,
                             int64_t batch_per_rank);

}  // namespace flat::train
