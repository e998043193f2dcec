#include "gl_functions.h"

#include <string>

#include "zsculpt/core/errors.h"

namespace zsculpt::render::detail {

void GlFunctions::load(const GlLoader& loader) {
#define ZSCULPT_GL_LOAD(type, name)                  \
  name = reinterpret_cast<type>(loader("gl" #name)); \
  if (name == nullptr) throw IOError("OpenGL: gl" #name " is not available");
  ZSCULPT_GL_FUNCTIONS(ZSCULPT_GL_LOAD)
#undef ZSCULPT_GL_LOAD
}

}  // namespace zsculpt::render::detail
