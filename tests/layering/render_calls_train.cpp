// Deliberately breaks the module map (docs/development.md): a program that
// links the render module alone and calls into train. It compiles (one
// include root) and must fail to link; the CTest test "layering" builds it
// and passes only on the linker's undefined reference to flat::train.
#include "flat/train/train_config.h"

int main() { return flat::train::describe_config().empty() ? 1 : 0; }
