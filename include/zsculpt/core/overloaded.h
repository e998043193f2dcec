#pragma once
// The visitor helper for std::visit over a std::variant of commands: one lambda per
// alternative, std::visit(Overloaded{[](const A&) {...}, [](const B&) {...}}, v).

namespace zsculpt {

template <class... Ts>
struct Overloaded : Ts... {
  using Ts::operator()...;
};
template <class... Ts>
Overloaded(Ts...) -> Overloaded<Ts...>;

}  // namespace zsculpt
