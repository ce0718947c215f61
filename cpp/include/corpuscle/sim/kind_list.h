// Lists of index plug-ins and of scene kinds, and the dispatch by name they give.
//
// A kind's index plug-ins are an IndexList of its index types (each with a static `name`),
// the first the default: the kind's index names and its make-by-index-name come from it.
// A kind's entry in the registry is a type with
//   static constexpr const char* name;                      // the kind's name
//   using Indexes = IndexList<...>;                           // its index plug-ins
//   template <class Exec> static std::unique_ptr<Sim> make(Exec&&, const SimRequest&);
//   template <class Exec> static double bytes(const SimRequest&);  // bytes_needed
// and the one list of kinds (sim/kinds.h) is a KindList of those entries: the registry's
// kinds() and bytes_needed, and each backend's make_sim, read it.
#pragma once
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "corpuscle/core/error.h"

namespace cps {

namespace detail {
template <class A, class...>
struct FirstOf {
  using type = A;
};
}  // namespace detail

template <class First, class... Rest>
struct IndexList {
  using Default = First;
  static const std::vector<std::string>& names() {
    static const std::vector<std::string> n = {First::name, Rest::name...};
    return n;
  }
  static std::string joined() {
    std::string s;
    for (const std::string& n : names()) s += (s.empty() ? "" : ", ") + n;
    return s;
  }
  // f(Index{}) for the index named `index` (empty: the default); an unknown name throws
  // naming the kind and its indexes
  template <class F>
  static auto with(const std::string& kind, const std::string& index, F&& f) -> decltype(f(First{})) {
    const std::string& want = index.empty() ? names()[0] : index;
    decltype(f(First{})) out{};
    bool found = false;
    auto pick = [&](auto tag) {
      if (!found && want == decltype(tag)::name) {
        out = f(tag);
        found = true;
      }
    };
    pick(First{});
    (pick(Rest{}), ...);
    if (!found) throw Error(kind + ": unknown index '" + want + "' (indexes: " + joined() + ")");
    return out;
  }
};

// an entry's `static constexpr bool hidden = true`: a kind built for tests
template <class K, class = void>
struct kind_hidden : std::false_type {};
template <class K>
struct kind_hidden<K, std::void_t<decltype(K::hidden)>> : std::bool_constant<K::hidden> {};

template <class... Kinds>
struct KindList {
  // (name, index names, hidden) of every kind, in the list's order
  template <class Info>
  static std::vector<Info> infos() {
    return {Info{Kinds::name, Kinds::Indexes::names(), kind_hidden<Kinds>::value}...};
  }
  // f(Kind{}) for the kind named `kind`; an unknown name throws
  template <class F>
  static auto with(const std::string& kind, F&& f) -> decltype(f(typename detail::FirstOf<Kinds...>::type{})) {
    decltype(f(typename detail::FirstOf<Kinds...>::type{})) out{};
    bool found = false;
    auto pick = [&](auto tag) {
      if (!found && kind == decltype(tag)::name) {
        out = f(tag);
        found = true;
      }
    };
    (pick(Kinds{}), ...);
    if (!found) throw Error("unknown scene kind '" + kind + "'");
    return out;
  }
};

}  // namespace cps
