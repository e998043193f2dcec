#include "zsculpt/cli/cli.h"

int main(int argc, char** argv) {
  return zsculpt::cli::run(argc, argv);
}
